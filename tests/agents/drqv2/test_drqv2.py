"""DrQ-v2's fidelity to the authors' code (facebookresearch/drqv2).

Every expected value is re-derived here in numpy from the authors' code (cited in each test),
not by calling the code under test; the networks' forward passes are checked once against numpy
and then used as building blocks. Tiny widths and batches: the file runs in seconds.
"""

from __future__ import annotations

import ast
import collections
import inspect
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vsgjax.agents.drqv2 import distributions as dist
from vsgjax.agents.drqv2 import losses, presets, schedule
from vsgjax.agents.drqv2.agent import DrQV2Agent
from vsgjax.agents.drqv2.augment import random_shift, shift_crop
from vsgjax.agents.drqv2.networks import Encoder, encoder_size, scale_pixels
from vsgjax.config.schema import apply_values, default_config

IMAGE = {"image": (16, 16, 3)}
VECTOR = {"vector": (5,)}
ACTION_DIM = 2
TINY = {"drq.hidden": 16, "drq.feature_dim": 8, "drq.cnn_depth": 4, "drq.shift_pad": 2,
        "drq.std_steps": 1000, "train.batch": 4, "train.prefill": 100, "env.action_repeat": 2,
        "train.train_every": 2, "drq.lr": 3e-3}  # a large step: one update's changes show


def make_agent(obs=IMAGE, **overrides) -> DrQV2Agent:
    config = apply_values(default_config("drqv2"), {**TINY, **{k.replace("__", "."): v
                                                              for k, v in overrides.items()}})
    return DrQV2Agent(config, obs, ACTION_DIM, False)


@pytest.fixture(scope="module")
def image_agent():
    agent = make_agent()
    return agent, agent.init(jax.random.key(0))


@pytest.fixture(scope="module")
def vector_agent():
    agent = make_agent(VECTOR)
    return agent, agent.init(jax.random.key(1))


# --- numpy references -------------------------------------------------------------------------

def np_conv(x, kernel, bias, stride):
    """``nn.Conv2d(k, stride)`` without padding, on [H, W, Cin] with an HWIO kernel."""
    k = kernel.shape[0]
    out_h, out_w = (x.shape[0] - k) // stride + 1, (x.shape[1] - k) // stride + 1
    y = np.zeros((out_h, out_w, kernel.shape[-1]))
    for i in range(out_h):
        for j in range(out_w):
            patch = x[i * stride:i * stride + k, j * stride:j * stride + k]
            y[i, j] = np.einsum("abc,abcd->d", patch, kernel)
    return y + bias


def np_dense(p, x):
    return x @ np.asarray(p["kernel"], np.float64) + np.asarray(p["bias"], np.float64)


def np_trunk(p, x):
    """Linear -> LayerNorm (torch: eps 1e-5, biased variance) -> Tanh."""
    h = np_dense(p["dense"], x)
    h = (h - h.mean(-1, keepdims=True)) / np.sqrt(h.var(-1, keepdims=True) + 1e-5)
    return np.tanh(h * np.asarray(p["norm"]["scale"]) + np.asarray(p["norm"]["bias"]))


def np_mlp(p, x):
    x = np.maximum(np_dense(p["dense0"], x), 0)
    x = np.maximum(np_dense(p["dense1"], x), 0)
    return np_dense(p["dense2"], x)


def np_actor(p, feat):
    """``Actor.forward``: mu = tanh(policy(trunk(obs)))."""
    return np.tanh(np_mlp(p["policy"], np_trunk(p["trunk"], feat)))


def np_critic(p, feat, action):
    """``Critic.forward``: Q1, Q2 of cat([trunk(obs), action])."""
    h = np.concatenate([np_trunk(p["trunk"], feat), action], -1)
    return np_mlp(p["q1"], h), np_mlp(p["q2"], h)


def np_clamp(x):
    """``TruncatedNormal._clamp``'s value."""
    return np.clip(x, -1 + 1e-6, 1 - 1e-6)


def np_grid_sample(image, grid):
    """``F.grid_sample(mode='bilinear', padding_mode='zeros', align_corners=False)`` of one
    [C, H, W] image at a [h, w, 2] grid of (x, y) in [-1, 1] (float64)."""
    channels, height, width = image.shape
    out = np.zeros((channels,) + grid.shape[:2])
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            x = ((grid[i, j, 0] + 1) * width - 1) / 2  # unnormalize, align_corners=False
            y = ((grid[i, j, 1] + 1) * height - 1) / 2
            x0, y0 = math.floor(x), math.floor(y)
            for yy, wy in ((y0, y0 + 1 - y), (y0 + 1, y - y0)):
                for xx, wx in ((x0, x0 + 1 - x), (x0 + 1, x - x0)):
                    if 0 <= yy < height and 0 <= xx < width:
                        out[:, i, j] += wy * wx * image[:, yy, xx]
    return out


def np_random_shifts_aug(image, shift_x, shift_y, pad):
    """``RandomShiftsAug.forward`` on one [C, h, h] image with a given integer shift: replicate
    padding, then the authors' base grid plus ``shift * 2 / (h + 2 pad)`` through grid_sample."""
    _, h, _ = image.shape
    padded = np.pad(image, ((0, 0), (pad, pad), (pad, pad)), mode="edge")
    eps = 1.0 / (h + 2 * pad)
    arange = np.linspace(-1.0 + eps, 1.0 - eps, h + 2 * pad)[:h]
    arange = np.repeat(arange[None], h, 0)[:, :, None]  # [h, h, 1]: x varies along columns
    base_grid = np.concatenate([arange, arange.transpose(1, 0, 2)], axis=2)
    shift = np.array([shift_x, shift_y], np.float64) * 2.0 / (h + 2 * pad)
    return np_grid_sample(padded, base_grid + shift)


def frame_stack_wrapper(frames, num_frames):
    """``dmc.FrameStackWrapper``: reset fills the deque with the first frame, each step appends;
    the observation concatenates the deque along channels (CHW frames)."""
    stack, out = collections.deque([], maxlen=num_frames), []
    for t, frame in enumerate(frames):
        pixels = frame.transpose(2, 0, 1).copy()
        for _ in range(num_frames if t == 0 else 1):
            stack.append(pixels)
        out.append(np.concatenate(list(stack), axis=0))
    return np.stack(out)


def replay_sample(episode, idx, nstep, gamma):
    """``ReplayBuffer._sample`` for a given ``idx`` (authors' episode: observation, action,
    reward, discount; index 0 is the reset's dummy transition)."""
    obs = episode["observation"][idx - 1]
    action = episode["action"][idx]
    next_obs = episode["observation"][idx + nstep - 1]
    reward = np.zeros_like(episode["reward"][idx])
    discount = np.ones_like(episode["discount"][idx])
    for i in range(nstep):
        step_reward = episode["reward"][idx + i]
        reward += discount * step_reward
        discount *= episode["discount"][idx + i] * gamma
    return obs, action, reward, discount, next_obs


def random_episode(rng, length, spec=IMAGE, terminal=True):
    """An episode in vsgjax's format (action/reward of step 0 zero, terminal at the end)."""
    episode = {"action": rng.uniform(-1, 1, (length, ACTION_DIM)).astype(np.float32),
               "reward": rng.normal(size=length).astype(np.float32),
               "is_first": np.arange(length) == 0,
               "is_terminal": (np.arange(length) == length - 1) & terminal}
    episode["action"][0], episode["reward"][0] = 0, 0
    for key, shape in spec.items():
        episode[key] = (rng.integers(0, 256, (length, *shape), np.uint8) if len(shape) == 3
                        else rng.normal(size=(length, *shape)).astype(np.float32))
    return episode


def windows(episode, starts, history, length):
    """What the replay samples: steps ``start - history .. start + length - 1``, the ones before
    the episode's first step edge-padded with it."""
    index = np.array([np.maximum(np.arange(s - history, s + length), 0) for s in starts])
    return {key: value[index] for key, value in episode.items()}


def image_batch(agent, seed=0, batch=4):
    needs = agent.replay
    rng = np.random.default_rng(seed)
    episode = random_episode(rng, 12)
    starts = rng.integers(0, 12 - needs.length + 1, batch)
    return windows(episode, starts, needs.history, needs.length)


def vector_batch(agent, seed=0, batch=4):
    needs = agent.replay
    rng = np.random.default_rng(seed)
    episode = random_episode(rng, 12, VECTOR)
    starts = rng.integers(0, 12 - needs.length + 1, batch)
    return windows(episode, starts, needs.history, needs.length)


def leaves(tree):
    return [np.asarray(x) for x in jax.tree.leaves(tree)]


# --- encoder ----------------------------------------------------------------------------------

def test_encoder_has_39200_features_at_84x84():
    """``drqv2.py`` ``Encoder``: ``repr_dim = 32 * 35 * 35`` for 84x84x(3*3) observations:
    84 -> 41 -> 39 -> 37 -> 35 with 3x3 kernels, strides 2, 1, 1, 1 and no padding."""
    size = 84
    for stride in (2, 1, 1, 1):
        size = (size - 3) // stride + 1
    assert size * size * 32 == 32 * 35 * 35 == 39_200 == encoder_size(84, 84, 32)
    obs = jax.ShapeDtypeStruct((1, 84, 84, 9), jnp.uint8)
    params = jax.eval_shape(Encoder(32).init, jax.random.key(0), obs)["params"]
    assert jax.eval_shape(Encoder(32).apply, {"params": params}, obs).shape == (1, 39_200)
    assert [params[f"conv{i}"]["kernel"].shape for i in range(4)] == [
        (3, 3, 9, 32), (3, 3, 32, 32), (3, 3, 32, 32), (3, 3, 32, 32)]


def test_encoder_matches_numpy_conv_stack(image_agent):
    """``Encoder.forward``: ``obs / 255 - 0.5``, then Conv(s=2) ReLU, 3x Conv(s=1) ReLU, no
    padding, flattened; checked against numpy convolutions, and the scaling's end points."""
    agent, state = image_agent
    rng = np.random.default_rng(3)
    obs = rng.integers(0, 256, (2, 16, 16, 9), np.uint8)
    got = np.asarray(agent.encode(state.params["encoder"], jnp.asarray(obs)))
    p = jax.tree.map(lambda x: np.asarray(x, np.float64), state.params["encoder"])
    for b in range(2):
        x = obs[b] / 255.0 - 0.5
        for i, stride in enumerate((2, 1, 1, 1)):
            x = np.maximum(np_conv(x, p[f"conv{i}"]["kernel"], p[f"conv{i}"]["bias"], stride), 0)
        assert x.shape == (1, 1, 4)  # 16 -> 7 -> 5 -> 3 -> 1
        np.testing.assert_allclose(got[b], x.reshape(-1), rtol=1e-4, atol=1e-5)
    scaled = np.asarray(scale_pixels(jnp.array([0, 128, 255], jnp.uint8)))
    np.testing.assert_allclose(scaled, [-0.5, 128 / 255 - 0.5, 0.5], atol=1e-7)


# --- augmentation -----------------------------------------------------------------------------

def test_integer_crop_equals_the_authors_grid_sample():
    """``drqv2.py`` ``RandomShiftsAug.forward``: replicate-pad, then ``F.grid_sample`` on the
    base grid ``linspace(-1 + 1/N, 1 - 1/N, N)[:h]`` shifted by ``s * 2 / N``; for every shift
    (x, y) in [0, 2 pad]^2 this equals cropping the padded image at rows y, columns x."""
    pad, size = 2, 6
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (size, size, 3), np.uint8)
    for sx in range(2 * pad + 1):
        for sy in range(2 * pad + 1):
            expected = np_random_shifts_aug(image.transpose(2, 0, 1).astype(np.float64),
                                            sx, sy, pad).transpose(1, 2, 0)
            got = shift_crop(jnp.asarray(image[None]), jnp.array([[sy, sx]]), pad)[0]
            assert got.dtype == jnp.uint8
            np.testing.assert_allclose(np.asarray(got, np.float64), expected, atol=1e-6)


def test_random_shift_draws_each_axis_and_sample_independently():
    """``RandomShiftsAug``: ``torch.randint(0, 2 * pad + 1, size=(n, 1, 1, 2))``: one shift per
    sample and axis, every value of [0, 2 pad] possible."""
    pad, n = 2, 400
    # each image holds its row index * 16 + column index, so a crop reveals its offset
    base = (np.arange(8)[:, None] * 16 + np.arange(8)[None, :]).astype(np.uint8)
    images = jnp.asarray(np.broadcast_to(base[None, :, :, None], (n, 8, 8, 1)))
    out = np.asarray(random_shift(images, jax.random.key(0), pad))
    padded = np.pad(base, pad, mode="edge")
    offsets = []
    for crop in out[:, :, :, 0]:
        found = [(r, c) for r in range(2 * pad + 1) for c in range(2 * pad + 1)
                 if np.array_equal(padded[r:r + 8, c:c + 8], crop)]
        assert found, "a crop that is no integer shift of the padded image"
        offsets.append(found[0])
    offsets = np.array(offsets)
    assert set(offsets[:, 0]) == set(offsets[:, 1]) == set(range(2 * pad + 1))
    assert not np.array_equal(offsets[:, 0], offsets[:, 1])


# --- the transition ---------------------------------------------------------------------------

@pytest.mark.parametrize("nstep, frame_stack", [(3, 3), (1, 3), (3, 1), (2, 2)])
def test_transition_matches_replay_buffer_sample(nstep, frame_stack):
    """``replay_buffer.py`` ``ReplayBuffer._sample`` on the authors' episode (``dmc.py``
    ``FrameStackWrapper`` observations, ``ExtendedTimeStepWrapper``'s dummy first transition,
    ``discount`` 0 at the terminal step) against :func:`losses.transition` on the replay's
    edge-padded windows of the same episode, for every ``idx`` the authors can draw."""
    gamma, length = 0.9, 9
    rng = np.random.default_rng(nstep * 10 + frame_stack)
    episode = random_episode(rng, length)
    authors = {"observation": frame_stack_wrapper(episode["image"], frame_stack),
               "action": episode["action"], "reward": episode["reward"][:, None],
               "discount": np.where(episode["is_terminal"], 0.0, 1.0)[:, None]
               .astype(np.float32)}
    history = frame_stack - 1
    idxs = np.arange(1, length - nstep + 1)  # np.random.randint(0, len - n + 1) + 1, len = T-1
    batch = windows(episode, idxs - 1, history, nstep + 1)
    got = losses.transition(jax.tree.map(jnp.asarray, batch), image_key="image", vector_keys=(),
                            frame_stack=frame_stack, history=history, nstep=nstep, gamma=gamma)
    for b, idx in enumerate(idxs):
        obs, action, reward, discount, next_obs = replay_sample(authors, idx, nstep, gamma)
        np.testing.assert_array_equal(np.asarray(got["obs"][b]).transpose(2, 0, 1), obs)
        np.testing.assert_array_equal(np.asarray(got["next_obs"][b]).transpose(2, 0, 1),
                                      next_obs)
        np.testing.assert_array_equal(np.asarray(got["action"][b]), action)
        np.testing.assert_allclose(np.asarray(got["reward"][b]), reward, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(np.asarray(got["discount"][b]), discount, rtol=1e-6)
    last = idxs[-1]  # the window that ends on the terminal step bootstraps nothing
    assert np.asarray(got["discount"])[-1, 0] == 0.0 and last + nstep - 1 == length - 1


def test_nstep_return_stops_at_a_terminal_step_inside_the_window():
    """``ReplayBuffer._sample``: ``reward += discount * r; discount *= episode_discount *
    gamma``: after a terminal step (episode discount 0) later rewards and the bootstrap get
    weight 0."""
    gamma = 0.5
    reward = jnp.array([[9.0, 1.0, 2.0, 4.0]])  # step 0 is the window's obs step
    terminal = jnp.array([[False, False, True, False]])
    ret, discount = losses.nstep_return(reward, terminal, 1, 3, gamma)
    assert float(ret[0, 0]) == pytest.approx(1.0 + gamma * 2.0)  # 4.0 is after the terminal
    assert float(discount[0, 0]) == 0.0
    ret, discount = losses.nstep_return(reward, jnp.zeros_like(terminal), 1, 3, gamma)
    assert float(ret[0, 0]) == pytest.approx(1.0 + gamma * 2.0 + gamma**2 * 4.0)
    assert float(discount[0, 0]) == pytest.approx(gamma**3)


def test_frame_stack_is_oldest_first_and_edge_padded_at_the_start():
    """``dmc.py`` ``FrameStackWrapper``: ``reset`` appends the first frame ``num_frames`` times,
    ``step`` appends the new one, the observation concatenates the deque (oldest first) along
    channels. Frames hold their step index, so the channels spell the stacked steps."""
    frames = np.arange(6, dtype=np.uint8)[:, None, None, None] * np.ones((1, 2, 2, 1), np.uint8)
    episode = {"image": frames, "action": np.zeros((6, 1), np.float32),
               "reward": np.zeros(6, np.float32), "is_first": np.arange(6) == 0,
               "is_terminal": np.zeros(6, bool)}
    batch = windows(episode, [0, 1, 3], history=2, length=3)
    got = losses.transition(jax.tree.map(jnp.asarray, batch), image_key="image", vector_keys=(),
                            frame_stack=3, history=2, nstep=2, gamma=0.99)
    steps = lambda x: np.asarray(x)[:, 0, 0, :].tolist()
    assert steps(got["obs"]) == [[0, 0, 0], [0, 0, 1], [1, 2, 3]]
    assert steps(got["next_obs"]) == [[0, 1, 2], [1, 2, 3], [3, 4, 5]]


# --- schedule and distribution ----------------------------------------------------------------

def test_std_schedule_and_its_agent_step():
    """``utils.py`` ``schedule('linear(init,final,duration)', step)``: ``mix = clip(step /
    duration, 0, 1); (1 - mix) * init + mix * final``, read at the authors' ``global_step``
    of an update: seed steps (``num_seed_frames // action_repeat``) + updates *
    ``update_every_steps``."""
    for step, expected in [(0, 1.0), (250, 0.775), (500, 0.55), (1000, 0.1), (5000, 0.1)]:
        assert float(schedule.linear(step, 1.0, 0.1, 1000)) == pytest.approx(expected, abs=1e-6)
    agent = make_agent()  # prefill 100 env steps, action repeat 2, an update every 2 steps
    for updates in (0, 10, 475, 2000):
        agent_step = 100 // 2 + updates * 2
        expected = (1 - min(agent_step / 1000, 1.0)) * 1.0 + min(agent_step / 1000, 1.0) * 0.1
        assert float(agent.std(updates)) == pytest.approx(expected, abs=1e-6)
        state = agent.init(jax.random.key(0))._replace(step=jnp.int32(updates))
        assert float(agent.acting_params(state)["std"]) == pytest.approx(expected, abs=1e-6)


def test_truncated_normal_clip_clamp_and_straight_through_gradient():
    """``utils.py`` ``TruncatedNormal.sample(clip)``: ``x = loc + clamp(eps * scale, -clip,
    clip)``, then ``_clamp``: the value clamped to [-1 + 1e-6, 1 - 1e-6], the gradient passed
    through (``x - x.detach() + clamped_x.detach()``)."""
    key = jax.random.key(7)
    mean = jnp.array([[-0.99, -0.2, 0.0, 0.5, 0.95, 0.999]] * 50)
    std, clip = 3.0, 0.3
    noise = np.asarray(jax.random.normal(key, mean.shape, jnp.float32), np.float64)
    for c in (clip, None):
        expected = np_clamp(np.asarray(mean) + (noise * std if c is None
                                                else np.clip(noise * std, -c, c)))
        got = np.asarray(dist.sample(key, mean, std, c))
        np.testing.assert_allclose(got, expected, atol=1e-6)
        assert got.max() <= 1 - 1e-6 + 1e-7 and got.min() >= -1 + 1e-6 - 1e-7
    clipped = np.asarray(dist.sample(key, mean, std, clip))
    assert np.all(np.abs(np.clip(clipped, -0.99, 0.99) - np.clip(np.asarray(mean), -0.99, 0.99))
                  <= clip + 1e-6)
    unclipped = np.asarray(dist.sample(key, mean, std, None))
    assert np.abs(unclipped - np.asarray(mean)).max() > 0.5  # no clip: wide noise
    grad = jax.grad(lambda m: jnp.sum(dist.sample(key, m, std, clip)))(mean)
    np.testing.assert_array_equal(np.asarray(grad), 1.0)  # even where the value was clamped


def test_truncated_normal_log_prob_and_entropy_are_the_normals():
    """``TruncatedNormal`` subclasses ``torch.distributions.Normal``: ``log_prob(x) =
    -(x - loc)^2 / (2 scale^2) - log scale - log sqrt(2 pi)``, ``entropy = 0.5 + 0.5 log(2 pi)
    + log scale``."""
    mean, std = np.array([0.1, -0.4]), 0.3
    x = np.array([0.5, 0.2])
    expected = -((x - mean) ** 2) / (2 * std**2) - np.log(std) - np.log(np.sqrt(2 * np.pi))
    np.testing.assert_allclose(np.asarray(dist.log_prob(jnp.asarray(x), jnp.asarray(mean), std)),
                               expected, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(dist.entropy(jnp.asarray(mean), std)),
                               0.5 + 0.5 * np.log(2 * np.pi) + np.log(std), rtol=1e-6)


# --- networks ---------------------------------------------------------------------------------

def test_orthogonal_init_with_zero_bias(image_agent):
    """``utils.py`` ``weight_init``: ``orthogonal_`` weights (Linear gain 1, Conv2d gain
    ``calculate_gain('relu')`` = sqrt 2), biases 0."""
    agent, state = image_agent
    params = state.params
    square = np.asarray(params["critic"]["q1"]["dense1"]["kernel"], np.float64)
    assert square.shape == (16, 16)
    np.testing.assert_allclose(square.T @ square, np.eye(16), atol=1e-5)
    np.testing.assert_allclose(square @ square.T, np.eye(16), atol=1e-5)
    # kernels are [in, out] = torch's W^T: orthonormal columns when in >= out, rows otherwise
    wide = np.asarray(params["actor"]["policy"]["dense0"]["kernel"], np.float64)  # [8, 16]
    np.testing.assert_allclose(wide @ wide.T, np.eye(8), atol=1e-5)
    tall = np.asarray(params["actor"]["policy"]["dense2"]["kernel"], np.float64)  # [16, 2]
    np.testing.assert_allclose(tall.T @ tall, np.eye(ACTION_DIM), atol=1e-5)
    conv = np.asarray(params["encoder"]["conv1"]["kernel"], np.float64).reshape(-1, 4)
    np.testing.assert_allclose(conv.T @ conv, 2.0 * np.eye(4), atol=1e-5)
    flat = jax.tree_util.tree_flatten_with_path(params)[0]
    biases = [leaf for path, leaf in flat if path[-1].key == "bias"]
    # encoder 4 convs; actor trunk (Linear, LayerNorm) + 3 Linear; critic and target: trunk + 6
    assert len(biases) == 4 + (2 + 3) + 2 * (2 + 6)
    assert all(np.all(np.asarray(b) == 0) for b in biases)
    scales = [leaf for path, leaf in flat if path[-1].key == "scale"]  # LayerNorm weight: 1
    assert len(scales) == 3 and all(np.all(np.asarray(s) == 1) for s in scales)


def test_actor_and_critic_forward_match_numpy(vector_agent):
    """``drqv2.py`` ``Actor.forward`` (tanh of policy(trunk)) and ``Critic.forward`` (Q1, Q2
    on cat(trunk(obs), action)), against numpy."""
    agent, state = vector_agent
    rng = np.random.default_rng(0)
    feat, action = rng.normal(size=(3, 5)), rng.uniform(-1, 1, (3, ACTION_DIM))
    params = jax.tree.map(lambda x: np.asarray(x, np.float64), state.params)
    np.testing.assert_allclose(
        np.asarray(agent.mean_action(state.params["actor"], jnp.asarray(feat, jnp.float32))),
        np_actor(params["actor"], feat), atol=1e-5)
    q1, q2 = agent.q_values(state.params["critic"], jnp.asarray(feat, jnp.float32),
                            jnp.asarray(action, jnp.float32))
    e1, e2 = np_critic(params["critic"], feat, action)
    np.testing.assert_allclose(np.asarray(q1), e1, atol=1e-5)
    np.testing.assert_allclose(np.asarray(q2), e2, atol=1e-5)
    assert not np.allclose(e1, e2)  # twin heads, their own weights


def test_actor_and_critic_have_separate_trunks(image_agent):
    """``drqv2.py``: ``Actor`` and ``Critic`` each build their own ``trunk`` (Linear ->
    LayerNorm -> Tanh); the critic target starts as the critic's copy (``load_state_dict``)."""
    agent, state = image_agent
    params = state.params
    assert set(params["actor"]) == {"trunk", "policy"}
    assert set(params["critic"]) == {"trunk", "q1", "q2"}
    assert not np.allclose(params["actor"]["trunk"]["dense"]["kernel"],
                           params["critic"]["trunk"]["dense"]["kernel"])
    for a, b in zip(leaves(params["critic"]), leaves(params["critic_target"]), strict=True):
        np.testing.assert_array_equal(a, b)
    feat = jax.random.normal(jax.random.key(1), (3, agent.repr_dim))
    bumped = jax.tree.map(lambda x: x + 0.5, params["critic"]["trunk"])
    critic = {**params["critic"], "trunk": bumped}
    mean = agent.mean_action(params["actor"], feat)
    assert not np.allclose(agent.q_values(critic, feat, mean)[0],
                           agent.q_values(params["critic"], feat, mean)[0])
    np.testing.assert_array_equal(agent.mean_action(params["actor"], feat), mean)


# --- the update -------------------------------------------------------------------------------

def test_target_uses_min_of_twin_target_q_and_clipped_next_action(vector_agent):
    """``drqv2.py`` ``update_critic``: ``next_action = dist.sample(clip=stddev_clip)``,
    ``target_Q = reward + discount * torch.min(target_Q1, target_Q2)`` with ``critic_target``."""
    agent, state = vector_agent
    params = dict(state.params)
    # a target critic unlike the critic, so that reading the wrong one shows
    rng = np.random.default_rng(1)
    target = jax.tree.map(
        lambda x: x + 0.3 * jnp.asarray(rng.normal(size=x.shape), jnp.float32), params["critic"])
    next_feat = jnp.asarray(rng.normal(size=(32, 5)), jnp.float32)
    reward = jnp.asarray(rng.normal(size=(32, 1)), jnp.float32)
    discount = jnp.asarray(rng.choice([0.0, 0.5, 0.9, 1.0], (32, 1)), jnp.float32)
    std, key = 2.0, jax.random.key(3)
    p = jax.tree.map(lambda x: np.asarray(x, np.float64), params)
    mean = np_actor(p["actor"], np.asarray(next_feat, np.float64))
    noise = np.asarray(jax.random.normal(key, mean.shape, jnp.float32), np.float64)
    next_action = np_clamp(mean + np.clip(noise * std, -0.3, 0.3))
    # shift Q2's output bias so that each head is the smaller one on about half the samples
    q1, q2 = np_critic(jax.tree.map(np.asarray, target), np.asarray(next_feat, np.float64),
                       next_action)
    shift = float(np.median(q1 - q2))
    target["q2"]["dense2"]["bias"] = target["q2"]["dense2"]["bias"] + shift
    params["critic_target"] = target
    got = np.asarray(agent.target_q(params, next_feat, reward, discount, jnp.float32(std), key))

    p = jax.tree.map(lambda x: np.asarray(x, np.float64), params)
    q1, q2 = np_critic(p["critic_target"], np.asarray(next_feat, np.float64), next_action)
    assert np.any(q1 < q2) and np.any(q2 < q1)  # the min picks from both heads
    expected = np.asarray(reward) + np.asarray(discount) * np.minimum(q1, q2)
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-4)


def test_critic_and_actor_losses():
    """``update_critic``: ``F.mse_loss(Q1, target_Q) + F.mse_loss(Q2, target_Q)``;
    ``update_actor``: ``-torch.min(Q1, Q2).mean()``; ``utils.soft_update_params``:
    ``tau * param + (1 - tau) * target_param``."""
    rng = np.random.default_rng(2)
    q1, q2, y = (rng.normal(size=(5, 1)) for _ in range(3))
    j = lambda x: jnp.asarray(x, jnp.float32)
    assert float(losses.critic_loss(j(q1), j(q2), j(y))) == pytest.approx(
        np.mean((q1 - y) ** 2) + np.mean((q2 - y) ** 2), rel=1e-5)
    assert float(losses.actor_loss(j(q1), j(q2))) == pytest.approx(
        -np.mean(np.minimum(q1, q2)), rel=1e-5)
    online, target = {"a": j(q1), "b": {"c": j(q2)}}, {"a": j(y), "b": {"c": j(q1)}}
    mixed = losses.polyak(online, target, 0.01)
    np.testing.assert_allclose(mixed["a"], 0.01 * q1 + 0.99 * y, rtol=1e-5)
    np.testing.assert_allclose(mixed["b"]["c"], 0.01 * q2 + 0.99 * q1, rtol=1e-5)


def test_actor_loss_trains_neither_encoder_nor_critic(image_agent):
    """``drqv2.py`` ``update``: ``update_actor(obs.detach(), step)`` (no encoder gradient) and
    only ``actor_opt`` steps on the actor loss (the critic's gradients from it are discarded:
    ``zero_grad(set_to_none=True)`` before the next critic step); the encoder learns from the
    critic loss (``encoder_opt.step()`` after ``critic_loss.backward()``)."""
    agent, state = image_agent
    obs = jnp.asarray(np.random.default_rng(0).integers(0, 256, (4, 16, 16, 9), np.uint8))
    std, key = agent.std(0), jax.random.key(0)

    def actor_loss(params):
        return agent.actor_objective(params, agent.encode(params["encoder"], obs), std, key)[0]

    grads = jax.jit(jax.grad(actor_loss))(state.params)
    assert all(np.all(g == 0) for g in leaves(grads["encoder"]) + leaves(grads["critic"]))
    assert any(np.any(g != 0) for g in leaves(grads["actor"]))

    action = jnp.zeros((4, ACTION_DIM))
    target = jnp.ones((4, 1))
    grads = jax.jit(jax.grad(lambda p: agent.critic_objective(p, obs, action, target)[0]))(
        state.params)
    assert any(np.any(g != 0) for g in leaves(grads["encoder"]))
    assert any(np.any(g != 0) for g in leaves(grads["critic"]))
    assert all(np.all(g == 0) for g in leaves(grads["actor"]) + leaves(grads["critic_target"]))


def test_train_step_follows_the_authors_update(image_agent):
    """``drqv2.py`` ``DrQV2Agent.update``: augment obs and next_obs separately, encode (next_obs
    without gradient), the critic's target from the current actor and target critic, the
    critic loss on the current encoder's features, then the actor loss on those (detached)
    features against the UPDATED critic, then ``soft_update_params(critic, critic_target,
    tau)`` with the updated critic. Every metric is recomputed here from the old state."""
    agent, state = image_agent
    batch = jax.tree.map(jnp.asarray, image_batch(agent))
    key = jax.random.key(5)
    new, metrics = agent.train_step(state, batch, key)
    aug_key, next_aug_key, target_key, actor_key = jax.random.split(key, 4)
    tr = agent.transition(batch)
    obs = random_shift(tr["obs"], aug_key, 2)
    next_obs = random_shift(tr["next_obs"], next_aug_key, 2)
    p = jax.tree.map(lambda x: np.asarray(x, np.float64), state.params)
    std = 1.0 + min((100 // 2) / 1000, 1) * (0.1 - 1.0)
    f64 = lambda x: np.asarray(x, np.float64)

    next_feat = f64(agent.encode(state.params["encoder"], next_obs))
    mean = np_actor(p["actor"], next_feat)
    noise = f64(jax.random.normal(target_key, mean.shape, jnp.float32))
    q1, q2 = np_critic(p["critic_target"], next_feat,
                       np_clamp(mean + np.clip(noise * std, -0.3, 0.3)))
    y = f64(tr["reward"]) + f64(tr["discount"]) * np.minimum(q1, q2)
    feat = f64(agent.encode(state.params["encoder"], obs))
    q1, q2 = np_critic(p["critic"], feat, f64(tr["action"]))
    mean = np_actor(p["actor"], feat)
    noise = f64(jax.random.normal(actor_key, mean.shape, jnp.float32))
    action = np_clamp(mean + np.clip(noise * std, -0.3, 0.3))
    new_critic = jax.tree.map(lambda x: np.asarray(x, np.float64), new.params["critic"])
    a1, a2 = np_critic(new_critic, feat, action)
    log_prob = -((action - mean) ** 2) / (2 * std**2) - np.log(std) - 0.5 * np.log(2 * np.pi)
    expected = {
        "critic/target_q": y.mean(), "critic/q1": q1.mean(), "critic/q2": q2.mean(),
        "critic/loss": np.mean((q1 - y) ** 2) + np.mean((q2 - y) ** 2),
        "actor/loss": -np.minimum(a1, a2).mean(), "actor/std": std,
        "actor/logprob": log_prob.sum(-1).mean(),
        "actor/entropy": ACTION_DIM * (0.5 + 0.5 * np.log(2 * np.pi) + np.log(std)),
        "data/batch_reward": f64(tr["reward"]).mean()}
    assert set(metrics) == set(expected)
    for name, value in expected.items():
        assert metrics[name].dtype == jnp.float32 and metrics[name].shape == ()
        assert float(metrics[name]) == pytest.approx(value, rel=1e-4, abs=1e-5), name
    for old_target, critic, target in zip(leaves(state.params["critic_target"]),
                                          leaves(new.params["critic"]),
                                          leaves(new.params["critic_target"]), strict=True):
        np.testing.assert_allclose(target, 0.01 * critic + 0.99 * old_target,
                                   rtol=1e-5, atol=1e-7)
    assert int(new.step) == 1


@pytest.mark.parametrize("kind", ["image", "vector"])
def test_train_step_runs_and_changes_every_part(kind, image_agent, vector_agent):
    """One update changes the encoder (pixels), actor, critic and target critic, and counts."""
    agent, state = image_agent if kind == "image" else vector_agent
    batch = image_batch(agent) if kind == "image" else vector_batch(agent)
    new, metrics = agent.train_step(state, jax.tree.map(jnp.asarray, batch), jax.random.key(2))
    for part in ("encoder", "actor", "critic", "critic_target"):
        if kind == "vector" and part == "encoder":
            assert new.params["encoder"] == {}
            continue
        assert any(not np.array_equal(a, b)
                   for a, b in zip(leaves(state.params[part]), leaves(new.params[part]),
                                   strict=True)), part
    assert int(new.step) == int(state.step) + 1
    assert all(np.isfinite(float(v)) for v in metrics.values())
    if kind == "vector":
        assert agent.replay.history == 0


def test_train_step_is_deterministic(vector_agent):
    """The same key gives the same update; another key another one."""
    agent, state = vector_agent
    batch = jax.tree.map(jnp.asarray, vector_batch(agent, seed=4))
    one = agent.train_step(state, batch, jax.random.key(9))
    two = agent.train_step(state, batch, jax.random.key(9))
    for a, b in zip(leaves(one), leaves(two), strict=True):
        np.testing.assert_array_equal(a, b)
    three = agent.train_step(state, batch, jax.random.key(10))
    assert any(not np.array_equal(a, b)
               for a, b in zip(leaves(one[0].params), leaves(three[0].params), strict=True))


# --- acting -----------------------------------------------------------------------------------

def test_policy_refills_the_frame_stack_at_is_first(image_agent):
    """``dmc.py`` ``FrameStackWrapper``: ``reset`` fills every slot with the first frame,
    ``step`` drops the oldest; env 0 starts a new episode at t = 3, env 1 runs on."""
    agent, state = image_agent
    params = agent.acting_params(state)
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (6, 2, 16, 16, 3), np.uint8)
    is_first = np.zeros((6, 2), bool)
    is_first[0] = True
    is_first[3, 0] = True
    expected = [np.concatenate([frame_stack_wrapper(frames[:3, 0], 3),
                                frame_stack_wrapper(frames[3:, 0], 3)]),  # restarted at t = 3
                frame_stack_wrapper(frames[:, 1], 3)]
    carry = agent.initial_carry(2)
    assert carry.shape == (2, 16, 16, 9) and carry.dtype == jnp.uint8
    for t in range(6):
        obs = {"image": jnp.asarray(frames[t]), "is_first": jnp.asarray(is_first[t])}
        carry, action = agent.policy_step(params, carry, obs, jax.random.key(t), mode="eval")
        assert action.shape == (2, ACTION_DIM) and action.dtype == jnp.float32
        for env in range(2):
            np.testing.assert_array_equal(np.asarray(carry[env]).transpose(2, 0, 1),
                                          expected[env][t])
        feat = agent.encode(params["encoder"], carry)  # the policy reads the stack
        np.testing.assert_allclose(action, agent.mean_action(params["actor"], feat), atol=1e-6)


def test_eval_acts_with_the_mean_and_train_samples_without_clip(vector_agent):
    """``drqv2.py`` ``act``: eval ``dist.mean`` (= tanh mean of the actor); train
    ``dist.sample(clip=None)`` with the schedule's std (noise beyond ``stddev_clip``),
    clamped inside (-1, 1)."""
    agent, state = vector_agent
    params = agent.acting_params(state)
    obs = np.random.default_rng(0).normal(size=(64, 5)).astype(np.float32)
    inputs = {"vector": jnp.asarray(obs), "is_first": jnp.zeros(64, bool)}
    carry = agent.initial_carry(64)
    _, eval_action = agent.policy_step(params, carry, inputs, jax.random.key(0), mode="eval")
    p = jax.tree.map(lambda x: np.asarray(x, np.float64), state.params)
    mean = np_actor(p["actor"], obs.astype(np.float64))
    np.testing.assert_allclose(np.asarray(eval_action), mean, atol=1e-5)
    _, again = agent.policy_step(params, carry, inputs, jax.random.key(1), mode="eval")
    np.testing.assert_array_equal(eval_action, again)

    key = jax.random.key(2)
    _, action = agent.policy_step(params, carry, inputs, key, mode="train")
    std = float(params["std"])
    noise = np.asarray(jax.random.normal(key, mean.shape, jnp.float32), np.float64)
    np.testing.assert_allclose(np.asarray(action), np_clamp(mean + noise * std), atol=1e-5)
    assert np.abs(np.asarray(action) - mean).max() > 0.3  # not clipped at stddev_clip
    assert np.abs(np.asarray(action)).max() <= 1.0
    with pytest.raises(ValueError, match="unknown policy mode"):
        agent.policy_step(params, carry, inputs, key, mode="greedy")


# --- interface and presets --------------------------------------------------------------------

def test_replay_needs_and_rejections():
    """``replay_buffer.py``: obs at ``idx - 1`` to next_obs at ``idx + n - 1`` is ``n + 1``
    steps; ``frame_stack - 1`` steps of history make the first stack (none for vectors)."""
    assert make_agent().replay == (4, 2)
    assert make_agent(drq__nstep=1, drq__frame_stack=2).replay == (2, 1)
    assert make_agent(VECTOR).replay == (4, 0)
    assert make_agent(VECTOR).initial_carry(3).shape == (3, 0)
    with pytest.raises(ValueError, match="continuous"):
        DrQV2Agent(default_config("drqv2"), IMAGE, 3, True)
    with pytest.raises(ValueError, match="one image key or vector keys"):
        DrQV2Agent(default_config("drqv2"), {**IMAGE, **VECTOR}, 3, False)
    agent, batch = make_agent(VECTOR), vector_batch(make_agent(VECTOR))
    short = {k: v[:, 1:] for k, v in batch.items()}
    with pytest.raises(ValueError, match="windows of 4 steps"):
        agent.transition(short)


def test_presets_are_the_authors_config():
    """``cfgs/config.yaml`` (frame_stack 3, action_repeat 2, discount 0.99, num_seed_frames
    4000, eval_every_frames 10000, num_eval_episodes 10, replay_buffer_size 1e6, nstep 3,
    batch_size 256, lr 1e-4, feature_dim 50, critic_target_tau 0.01, update_every_steps 2,
    hidden_dim 1024, stddev_clip 0.3), ``cfgs/task/medium.yaml`` (3.1M frames, linear(1.0,
    0.1, 500000)), the walker and humanoid task files; pure data; every key valid."""
    dmc = presets.COLUMN["dmc"]
    authors = {"drq.frame_stack": 3, "env.action_repeat": 2, "drq.gamma": 0.99,
               "train.prefill": 4000, "train.eval_every": 10_000, "train.eval_episodes": 10,
               "train.replay_capacity": 1_000_000, "drq.nstep": 3, "train.batch": 256,
               "drq.lr": 1e-4, "drq.feature_dim": 50, "drq.tau": 0.01, "train.train_every": 2,
               "drq.hidden": 1024, "drq.std_clip": 0.3, "drq.std_start": 1.0,
               "drq.std_end": 0.1, "drq.std_steps": 500_000, "train.steps": 3_100_000,
               "drq.cnn_depth": 32, "drq.shift_pad": 4, "env.image_size": 84}
    assert {key: dmc[key] for key in authors} == authors
    assert dmc["train.length"] == dmc["drq.nstep"] + 1
    assert presets.TASK["walker"] == {"drq.nstep": 1, "train.batch": 512}
    assert presets.TASK["humanoid"] == {"drq.lr": 8e-5, "drq.feature_dim": 100}
    assert presets.DIFFICULTY["easy"]["drq.std_steps"] == 100_000
    assert presets.DIFFICULTY["hard"]["drq.std_steps"] == 2_000_000
    bbs = presets.COLUMN["bbs"]
    assert (bbs["env.action_repeat"], bbs["env.time_limit"], bbs["env.image_size"]) == (4, 3000, 64)
    assert set(presets.SIZE) == {"paper", "small", "cpu", "debug"}
    tables = [*presets.COLUMN.values(), *presets.SIZE.values(), *presets.TASK.values(),
              *presets.TASK_ONLY.values(), *presets.DIFFICULTY.values()]
    for table in tables:
        apply_values(default_config("drqv2"), table)  # every key exists with its type
    tree = ast.parse(inspect.getsource(presets))
    assert not [node for node in ast.walk(tree) if isinstance(node, ast.Import | ast.ImportFrom)]
