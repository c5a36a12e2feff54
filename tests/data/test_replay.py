"""Replay: MCAP episode files (round trip, Foxglove schema, atomicity, corruption), sampler."""

import base64
import io
import json
import signal
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from vsgjax.data.replay import (
    CorruptEpisodeError,
    EpisodeStore,
    Replay,
    decode_episode,
    encode_episode,
    episode_length,
)

REPO_ROOT = Path(__file__).resolve().parents[2]


def make_episode(length, episode_id=0, channels=3, action_dim=2, seed=0, terminal=True):
    """A valid episode whose extra keys identify each step: (episode_id, step_id)."""
    rng = np.random.default_rng(seed)
    action = rng.normal(size=(length, action_dim)).astype(np.float32)
    action[0] = 0.0
    return {
        "image": rng.integers(0, 256, (length, 8, 6, channels), dtype=np.uint8),
        "action": action,
        "reward": rng.normal(size=length).astype(np.float32),
        "is_first": np.arange(length) == 0,
        "is_terminal": (np.arange(length) == length - 1) & terminal,
        "episode_id": np.full(length, episode_id, np.int64),
        "step_id": np.arange(length, dtype=np.int32),
        "metric": rng.normal(size=(length, 3)),  # float64, per-step vector
    }


def assert_same_episode(actual, expected):
    assert list(actual) == list(expected)
    for key, value in expected.items():
        assert actual[key].dtype == value.dtype, key
        assert actual[key].shape == value.shape, key
        np.testing.assert_array_equal(actual[key], value, err_msg=key)


# --- MCAP files --------------------------------------------------------------------------------


@pytest.mark.parametrize("channels", [3, 1])
def test_mcap_round_trip_is_bit_exact(tmp_path, channels):
    store = EpisodeStore(tmp_path)
    episode = make_episode(17, channels=channels)
    episode["reward"][3] = np.float32(1e-38)  # float32 values that are awkward in decimal
    episode["reward"][4] = np.float32(np.pi)
    path = store.write(episode)
    assert path.parent == tmp_path and path.suffix == ".mcap" and path.name.endswith("-17.mcap")
    (loaded,) = store.load()
    assert_same_episode(loaded, episode)


def test_mcap_file_follows_documented_foxglove_schema(tmp_path):
    episode = make_episode(4)
    reader = make_reader(io.BytesIO(encode_episode(episode)))
    messages = {}
    for schema, channel, message in reader.iter_messages():
        messages.setdefault(channel.topic, []).append((schema, channel, message))
    assert set(messages) == {f"/{key}" for key in episode}
    schema, channel, message = messages["/image"][2]
    assert (schema.name, schema.encoding, channel.message_encoding) == (
        "foxglove.RawImage", "jsonschema", "json")
    image = json.loads(message.data)
    assert (image["width"], image["height"], image["encoding"], image["step"]) == (6, 8, "rgb8", 18)
    assert image["timestamp"] == {"sec": 0, "nsec": 100_000_000} and message.sequence == 2
    pixels = np.frombuffer(base64.b64decode(image["data"]), np.uint8).reshape(8, 6, 3)
    np.testing.assert_array_equal(pixels, episode["image"][2])
    schema, channel, message = messages["/action"][1]
    assert schema.name == "vsgjax.action"
    assert channel.metadata == {"dtype": "float32", "shape": "[2]"}
    assert json.loads(message.data)["value"] == episode["action"][1].tolist()
    (meta,) = reader.iter_metadata()
    assert meta.name == "vsgjax.episode" and meta.metadata["length"] == "4"


def test_load_respects_step_limit_newest_first(tmp_path):
    store = EpisodeStore(tmp_path)
    for i, length in enumerate([10, 20, 30, 40]):
        store.write(make_episode(length, episode_id=i))
    ids = lambda episodes: [int(e["episode_id"][0]) for e in episodes]
    assert ids(store.load()) == [0, 1, 2, 3]
    assert ids(store.load(limit_steps=75)) == [2, 3]  # 40 + 30 fit, + 20 would not
    assert ids(store.load(limit_steps=39)) == []


def test_killed_writer_leaves_no_readable_file(tmp_path):
    """A writer SIGKILLed after writing the temp file, before the rename: nothing is loaded."""
    directory = tmp_path / "episodes"
    script = textwrap.dedent(f"""
        import os, signal
        import numpy as np
        from vsgjax.data.replay import EpisodeStore
        n = 30
        episode = {{"image": np.ones((n, 8, 8, 3), np.uint8),
                   "action": np.zeros((n, 2), np.float32), "reward": np.zeros(n, np.float32),
                   "is_first": np.arange(n) == 0, "is_terminal": np.zeros(n, bool)}}
        os.fsync = lambda fd: os.kill(os.getpid(), signal.SIGKILL)
        EpisodeStore({str(directory)!r}).write(episode)
    """)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=120,
                            cwd=REPO_ROOT)
    assert result.returncode == -signal.SIGKILL, result.stderr.decode()
    leftovers = list(directory.iterdir())
    assert len(leftovers) == 1 and leftovers[0].name.endswith(".tmp")
    assert leftovers[0].stat().st_size > 1000  # the whole episode, only the rename is missing
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert EpisodeStore(directory).load() == []


@pytest.mark.parametrize("damage", ["truncate", "garbage", "flip_byte", "empty"])
def test_corrupt_file_is_skipped_with_warning(tmp_path, damage):
    store = EpisodeStore(tmp_path)
    good = store.write(make_episode(12, episode_id=0))
    bad = store.write(make_episode(12, episode_id=1))
    data = bad.read_bytes()
    damaged = {
        "truncate": data[: len(data) // 2],
        "garbage": np.random.default_rng(0).integers(0, 256, len(data), np.uint8).tobytes(),
        "flip_byte": data[:400] + bytes([data[400] ^ 0xFF]) + data[401:],  # inside a chunk
        "empty": b"",
    }[damage]
    bad.write_bytes(damaged)
    with pytest.warns(UserWarning, match=bad.name):
        episodes = store.load()
    assert [int(e["episode_id"][0]) for e in episodes] == [0]
    assert good.exists()


@pytest.mark.parametrize(("claimed", "message"), [(b"6", r"lacks steps \[5\]"),
                                                 (b"4", "unexpected message .* sequence 4")])
def test_file_whose_channels_disagree_with_its_length_is_rejected(claimed, message):
    data = encode_episode(make_episode(5))
    stored_length = b"length\x01\x00\x00\x005"  # MCAP metadata map entry "length": "5"
    assert data.count(stored_length) == 1
    with pytest.raises(CorruptEpisodeError, match=message):
        decode_episode(data.replace(stored_length, stored_length[:-1] + claimed))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda e: e.pop("reward"), "lacks key 'reward'"),
        (lambda e: e.update(reward=e["reward"].astype(np.float64)), "reward"),
        (lambda e: e.update(image=e["image"].astype(np.float32)), "image"),
        (lambda e: e["is_first"].__setitem__(3, True), r"is_first .* at \[0, 3\]"),
        (lambda e: e["is_terminal"].__setitem__(0, True), "is_terminal"),
        (lambda e: e.update(action=e["action"][:-1]), "shared length"),
        (lambda e: e.update(image=e["image"][..., :2]), "1 or 3 channels"),
    ],
)
def test_invalid_episodes_are_rejected_with_clear_errors(change, message):
    episode = make_episode(6)
    change(episode)
    with pytest.raises(ValueError, match=message):
        episode_length(episode)


# --- in-memory sampler -------------------------------------------------------------------------


def filled_replay(lengths, capacity=10_000, length=5, seed=0, oversample_ends=False):
    replay = Replay(capacity, length, np.random.default_rng(seed), oversample_ends)
    for i, n in enumerate(lengths):
        replay.add_episode(make_episode(n, episode_id=i, seed=i))
    return replay


def test_sequences_never_cross_episode_boundaries():
    lengths = [7, 5, 30, 4, 12, 9]  # the 4-step episode is shorter than L = 5
    replay = filled_replay(lengths, capacity=60, length=5)  # evicts the 7-step episode; wraps
    assert replay.num_episodes == 5 and replay.num_steps == 60
    sources = {i: make_episode(n, episode_id=i, seed=i) for i, n in enumerate(lengths)}
    batch = replay.sample(2000)
    assert batch["image"].shape == (2000, 5, 8, 6, 3) and batch["image"].dtype == np.uint8
    assert batch["is_first"].dtype == bool and batch["reward"].dtype == np.float32
    episode_ids = batch["episode_id"]
    assert (episode_ids == episode_ids[:, :1]).all()  # one episode per sequence
    assert set(np.unique(episode_ids)) == {1, 2, 4, 5}  # evicted (0) and short (3) never
    assert (np.diff(batch["step_id"], axis=1) == 1).all()  # consecutive steps
    assert not batch["is_first"][:, 1:].any()
    np.testing.assert_array_equal(batch["is_first"][:, 0], batch["step_id"][:, 0] == 0)
    for row in range(0, 2000, 97):  # the stored data is the source data at those steps
        source, steps = sources[episode_ids[row, 0]], batch["step_id"][row]
        np.testing.assert_array_equal(batch["image"][row], source["image"][steps])
        np.testing.assert_array_equal(batch["action"][row], source["action"][steps])


def test_capacity_evicts_oldest_whole_episodes():
    replay = Replay(100, 5, 0)
    for i in range(10):
        replay.add_episode(make_episode(30, episode_id=i))
        assert replay.num_steps <= 100
    assert (replay.num_episodes, replay.num_steps) == (3, 90)
    assert set(np.unique(replay.sample(500)["episode_id"])) == {7, 8, 9}
    with pytest.raises(ValueError, match="exceeds the replay capacity 100"):
        replay.add_episode(make_episode(101))


def test_memory_per_step_keeps_images_uint8():
    replay = filled_replay([40, 40], capacity=1000)
    expected = 8 * 6 * 3 + 2 * 4 + 4 + 1 + 1 + 8 + 4 + 3 * 8  # image, action, reward, flags, extras
    assert replay.bytes_per_step == expected
    assert 80 * expected <= replay.nbytes <= 1000 * expected


def test_short_episodes_are_kept_but_never_sampled():
    replay = filled_replay([3, 4], length=5)
    assert (replay.num_episodes, replay.num_sequences) == (2, 0)
    with pytest.raises(ValueError, match="no episode of at least 5 steps"):
        replay.sample(1)


def test_uniform_over_sequences_weights_episodes_by_start_positions():
    replay = filled_replay([10, 30], length=5)  # 6 and 26 start positions
    starts = replay.sample(32_000)
    fraction_first = np.mean(starts["episode_id"][:, 0] == 0)
    assert abs(fraction_first - 6 / 32) < 0.01
    first_steps = starts["step_id"][:, 0][starts["episode_id"][:, 0] == 1]
    counts = np.bincount(first_steps, minlength=26)
    assert counts.min() > 0.8 * counts.mean() and len(counts) == 26  # uniform, none past 25


@pytest.mark.parametrize("oversample_ends", [False, True])
def test_oversample_ends_covers_the_last_steps_as_often_as_the_middle(oversample_ends):
    n, length, draws = 20, 5, 40_000
    replay = filled_replay([n], length=length, oversample_ends=oversample_ends)
    coverage = np.bincount(replay.sample(draws)["step_id"].ravel(), minlength=n) / draws
    if oversample_ends:  # the last and middle steps in a sample with probability L / n
        np.testing.assert_allclose(coverage[[-1, n // 2]], length / n, rtol=0.06)
        np.testing.assert_allclose(coverage[0], 1 / n, rtol=0.1)  # start k = 0 only
    else:  # the last step only in the sequence that starts at n - L: 1 / (n - L + 1)
        np.testing.assert_allclose(coverage[-1], 1 / (n - length + 1), rtol=0.1)
        np.testing.assert_allclose(coverage[n // 2], length / (n - length + 1), rtol=0.06)


def test_sampling_is_deterministic_given_the_seed():
    batches = [filled_replay([20, 30, 25], seed=seed).sample(8) for seed in (3, 3, 4)]
    for key in batches[0]:
        np.testing.assert_array_equal(batches[0][key], batches[1][key])
    assert not np.array_equal(batches[0]["step_id"], batches[2]["step_id"])


def test_replay_rejects_episodes_with_other_keys_or_shapes():
    replay = filled_replay([10])
    other = make_episode(10, action_dim=3)
    with pytest.raises(ValueError, match=r"episode\['action'\] is float32\[3\], replay stores"):
        replay.add_episode(other)
    extra = make_episode(10)
    extra["more"] = np.zeros(10, np.float32)
    with pytest.raises(ValueError, match="more"):
        replay.add_episode(extra)


def test_history_prepends_the_steps_before_and_repeats_the_first_at_an_episode_start():
    """``history=h``: each window is the h steps before a sequence and the sequence, from one
    episode; steps before the episode's first repeat it (frame stacking's edge padding)."""
    replay = Replay(capacity=100, length=4, rng=0, history=2)
    for episode_id, length in enumerate((5, 9)):
        replay.add_episode(make_episode(length, episode_id=episode_id, seed=episode_id))
    batch = replay.sample(500)
    assert batch["step_id"].shape == (500, 6)
    starts = batch["step_id"][:, 2]
    expected = np.maximum(starts[:, None] + np.arange(-2, 4), 0)
    np.testing.assert_array_equal(batch["step_id"], expected)
    assert (batch["episode_id"] == batch["episode_id"][:, :1]).all()
    assert {0, 1} <= set(starts.tolist())  # windows at the start are padded, not skipped
    assert starts.max() == 9 - 4


def test_history_must_not_be_negative():
    with pytest.raises(ValueError, match="history must be >= 0"):
        Replay(capacity=10, length=2, rng=0, history=-1)
