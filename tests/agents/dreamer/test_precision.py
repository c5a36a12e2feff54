"""Mixed precision (``model.precision``, vsgjax/agents/precision.py) on the real models at debug
size.

float32 must be the computation of before: its numbers are checked against values computed
by the code before precision existed (``REFERENCE``: bit for bit on the CPU that recorded them,
to float32 rounding on others; the float32 programs of every model's loss and agent update also
lowered to the same StableHLO text as before, checked once by hand).
bfloat16 must run every model's jitted agent update with float32 parameters, optimizer state
and gates that are exactly 0/1, with every matmul in bfloat16 and metrics close to float32's.
Each (model, precision) update compiles once (``_update``) and serves every test of it. As in
test_agent.py, VSG and DreamerV2 run by default; the other three models' bfloat16 updates
are marked slow (``make test`` runs them, ``make test-fast`` skips them).
"""

import functools
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.agents.dreamer.test_agent import make_batch
from tests.support.registry_names import models
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.agents.precision import compute_dtype, matmul
from vsgjax.config import ConfigError, make_config

# the Dreamer family's models with a decoder: the ones whose float32 updates are recorded below
MODELS = models(dreamer=True, prototypes=False)
GATED = models(gated=True, prototypes=False)
FAST = ("vsg", "dreamerv2")  # the paper's model and its baseline; the others' updates are slow
UPDATE_MODELS = [*FAST, *(pytest.param(m, marks=pytest.mark.slow) for m in MODELS
                          if m not in FAST)]
# float32 metrics of one agent update (init key 0, update key 1, `make_batch`), computed by the
# code before model.precision existed (XLA:CPU, jax 0.10.2). Exact for float32; the reference
# that bfloat16 is compared with.
REFERENCE = {
    "dreamerv1": {"wm/loss": 11813.6611328125, "wm/kl": 0.19828811287879944,
                 "wm/reward_loss": 1.1420493125915527, "wm/grad_norm": 16.521244049072266,
                 "actor/loss": 0.07793346047401428, "critic/loss": 0.5019916296005249,
                 "actor/grad_norm": 0.024831876158714294, "critic/grad_norm": 0.5362205505371094,
                 "imag/return": -0.21501699090003967},
    "dreamerv2": {"wm/loss": 11812.7861328125, "wm/kl": 0.08617731928825378,
                 "wm/reward_loss": 1.3618558645248413, "wm/grad_norm": 15.079994201660156,
                 "actor/loss": -0.07194831222295761, "critic/loss": 0.527163028717041,
                 "actor/grad_norm": 0.24358177185058594, "critic/grad_norm": 0.2625589072704315,
                 "imag/return": -0.05556188151240349},
    "vsg": {"wm/loss": 11812.603515625, "wm/kl": 0.037896402180194855,
           "wm/reward_loss": 1.0997101068496704, "wm/grad_norm": 15.668978691101074,
           "actor/loss": -0.025097619742155075, "critic/loss": 0.5133157968521118,
           "actor/grad_norm": 0.012067166157066822, "critic/grad_norm": 0.18422862887382507,
           "imag/return": 0.027063341811299324},
    "svsg": {"wm/loss": 11814.4755859375, "wm/kl": 0.21316027641296387,
            "wm/reward_loss": 1.3335952758789062, "wm/grad_norm": 18.117650985717773,
            "actor/loss": 0.24071110785007477, "critic/loss": 1.2999900579452515,
            "actor/grad_norm": 0.01728609763085842, "critic/grad_norm": 2.980119228363037,
            "imag/return": -0.36715930700302124},
    "ssm": {"wm/loss": 11813.6806640625, "wm/kl": 0.9280776977539062,
           "wm/reward_loss": 1.173035979270935, "wm/grad_norm": 17.030963897705078,
           "actor/loss": -0.16678178310394287, "critic/loss": 0.496447890996933,
           "actor/grad_norm": 0.0663064569234848, "critic/grad_norm": 0.456672728061676,
           "imag/return": 0.2854248285293579},
}
# float64 sum of every parameter after that update, float32 (exact; same provenance).
REFERENCE_PARAM_SUM = {"vsg": -42.52956275058477}
# float32 world-model loss terms of the same update (recorded with REFERENCE's setup; the terms
# of each model add up to its REFERENCE wm/loss; wm/kl is in REFERENCE).
REFERENCE_TERMS = {
    "dreamerv1": {"wm/image_loss": 11810.7060546875, "wm/reward_loss": 1.1420493125915527,
                  "wm/discount_loss": 0.8130720853805542, "wm/kl_loss": 1.0},
    "dreamerv2": {"wm/image_loss": 11810.6474609375, "wm/reward_loss": 1.3618558645248413,
                  "wm/discount_loss": 0.6905609965324402, "wm/kl_loss": 0.08617731928825378},
    "vsg": {"wm/image_loss": 11810.7890625, "wm/reward_loss": 1.0997101068496704,
            "wm/discount_loss": 0.6576952338218689, "wm/kl_loss": 0.037896402180194855,
            "wm/gate_loss": 0.01944596879184246, "wm/gate_kl": 0.1944596767425537},
    "svsg": {"wm/image_loss": 11811.462890625, "wm/reward_loss": 1.3335952758789062,
             "wm/discount_loss": 0.6094526052474976, "wm/kl_loss": 1.0,
             "wm/gate_loss": 0.07016357779502869, "wm/gate_kl": 0.7016357779502869},
    "ssm": {"wm/image_loss": 11810.7529296875, "wm/reward_loss": 1.173035979270935,
            "wm/discount_loss": 0.8270946741104126, "wm/kl_loss": 0.9280776977539062},
}
# bfloat16 against float32: the other metrics (observed at most 3e-2 relative, on imag/return)
RTOL, ATOL = 5e-2, 1e-3
# and each world-model loss term: (atol in nats, rtol); see test_bfloat16_loss_terms_are_float32s
TERM_TOLERANCE = {"wm/image_loss": (5e-3, 0.0), "wm/reward_loss": (5e-3, 0.0),
                  "wm/discount_loss": (5e-3, 0.0), "wm/kl": (3e-4, 2e-2),
                  "wm/kl_loss": (3e-4, 2e-2), "wm/gate_kl": (1e-3, 0.0),
                  "wm/gate_loss": (1e-4, 0.0), "wm/loss": (3e-2, 0.0)}
BF16_DOT = re.compile(r"stablehlo\.dot_general.*\(tensor<[^>]*xbf16>, tensor<[^>]*xbf16>\)")


def make_agent(model: str, precision: str) -> DreamerAgent:
    config = make_config("bbs_basic", model, "debug", [f"model.precision={precision}"])
    discrete = model == "dreamerv2"
    return DreamerAgent(config, (64, 64, 3), 3 if discrete else 2, discrete)


@functools.cache
def _setup(model: str, precision: str):
    """(agent, batch, initial state)."""
    agent = make_agent(model, precision)
    return agent, make_batch(agent.action_dim, agent.discrete), agent.init(jax.random.PRNGKey(0))


@functools.cache
def _update(model: str, precision: str):
    """(agent, batch, state_0, state_1, metrics_1, StableHLO text of the update)."""
    agent, batch, state = _setup(model, precision)
    key = jax.random.PRNGKey(1)
    lowered = agent.train_step.lower(agent, state, batch, key)
    new_state, metrics = lowered.compile()(state, batch, key)
    return agent, batch, state, new_state, jax.device_get(metrics), lowered.as_text()


def _float32_leaves(tree) -> bool:
    return all(x.dtype == jnp.float32 for x in jax.tree.leaves(tree)
               if jnp.issubdtype(x.dtype, jnp.floating))


# --- the policy -------------------------------------------------------------------------------

def test_unknown_precision_is_a_config_error():
    with pytest.raises(ConfigError, match=r"'float16'.*float32, bfloat16"):
        make_config("bbs_basic", "vsg", "debug", overrides=["model.precision=float16"])
    with pytest.raises(ValueError, match="float16"):
        compute_dtype("float16")


def test_matmul_rounds_its_inputs_and_accumulates_in_float32():
    x, w = jax.random.normal(jax.random.PRNGKey(0), (3, 4, 64)), jnp.linspace(-1, 1, 64 * 5)
    w = w.reshape(64, 5)
    low = matmul(x, w, jnp.bfloat16)
    rounded = lambda a: a.astype(jnp.bfloat16).astype(jnp.float32)
    assert low.dtype == jnp.float32
    np.testing.assert_allclose(low, rounded(x) @ rounded(w), rtol=1e-5, atol=1e-5)
    assert np.array_equal(matmul(x, w), x @ w)


def test_matmul_gradient_is_float32_and_close_to_float32s():
    x, w = jax.random.normal(jax.random.PRNGKey(0), (7, 16)), jnp.ones((16, 3)) / 4
    loss = lambda x, w, dtype: jnp.sum(jnp.sin(matmul(x, w, dtype)))
    exact = jax.grad(loss, (0, 1))(x, w, jnp.float32)
    low = jax.grad(loss, (0, 1))(x, w, jnp.bfloat16)
    for a, b in zip(exact, low, strict=True):
        assert b.dtype == jnp.float32
        np.testing.assert_allclose(b, a, rtol=2e-2, atol=2e-2)


# --- float32: unchanged -----------------------------------------------------------------------

def test_float32_update_is_unchanged():
    """Bit-identical on the CPU it was recorded on; other CPUs' XLA code may differ in the last
    bits, so the check allows float32 rounding (any real change is far larger)."""
    _, _, _, state, metrics, text = _update("vsg", "float32")
    for name, value in REFERENCE["vsg"].items():
        np.testing.assert_allclose(float(metrics[name]), value, rtol=1e-5, atol=1e-7,
                                   err_msg=name)
    param_sum = sum(np.asarray(x, np.float64).sum() for x in jax.tree.leaves(state.params))
    np.testing.assert_allclose(float(param_sum), REFERENCE_PARAM_SUM["vsg"], rtol=1e-6)
    assert "bf16" not in text


def test_every_model_has_its_float32_reference():
    """A model added to the registry fails here until its float32 update is recorded."""
    assert set(REFERENCE) == set(REFERENCE_TERMS) == set(MODELS)


@pytest.mark.parametrize("model", MODELS)
def test_float32_programs_have_no_bfloat16(model):
    agent = make_agent(model, "float32")
    batch = make_batch(agent.action_dim, agent.discrete)
    state = jax.eval_shape(agent.init, jax.random.PRNGKey(0))
    text = agent.train_step.lower(agent, state, batch, jax.random.PRNGKey(1)).as_text()
    assert "stablehlo.dot_general" in text and "bf16" not in text


# --- bfloat16 ---------------------------------------------------------------------------------

@pytest.mark.parametrize("model", UPDATE_MODELS)
def test_bfloat16_update_is_finite_float32_and_close_to_float32(model):
    _, _, state, new_state, metrics, _ = _update(model, "bfloat16")
    assert all(np.isfinite(v) for v in metrics.values()), metrics
    for name, value in REFERENCE[model].items():
        if name not in TERM_TOLERANCE:
            np.testing.assert_allclose(metrics[name], value, rtol=RTOL, atol=ATOL, err_msg=name)
    assert _float32_leaves(new_state.params) and _float32_leaves(new_state.opt)
    assert jax.tree.structure(new_state) == jax.tree.structure(state)


@pytest.mark.parametrize("model", UPDATE_MODELS)
def test_bfloat16_loss_terms_are_float32s(model):
    """Each world-model loss term of the bfloat16 update against float32's, in nats.

    Measured bfloat16 - float32 (largest over ``MODELS``, the model in brackets): image
    9.8e-4 (dreamerv1/v2: one float32 ulp at 11,810; vsg, svsg, ssm 0), reward 1.4e-3 (svsg),
    discount 9.6e-4 (svsg), KL 6.4e-3 (ssm, 0.7% of 0.93; the others <= 5.6e-4, <= 0.3%),
    gate KL 2.4e-4 (svsg; vsg 9.4e-5), gate loss 2.4e-5 (svsg), total 8.8e-3 (ssm).

    Each tolerance is at least 3x its largest measured difference, so bfloat16's rounding
    passes it, and small beside the term it checks: the image's 5e-3 nats is 1e-5 of its ~520
    nats above the Gaussian constant, the reward's and the discount's 5e-3 at most 0.8% of
    theirs, the gate KL's and the gate loss's 0.5%, the KL's 2% + 3e-4 nats (ssm's 0.7% sets
    it). A term that a bug moves by more than that fails, whereas the check of the total alone
    allowed +-1.2 nats, more than the reward and KL terms together. The KL is checked
    unclamped (``wm/kl``) besides ``wm/kl_loss``, which the free nats hold at 1.0 for
    dreamerv1 and svsg.
    """
    metrics = _update(model, "bfloat16")[4]
    reference = {**REFERENCE_TERMS[model], "wm/kl": REFERENCE[model]["wm/kl"],
                 "wm/loss": REFERENCE[model]["wm/loss"]}
    expected = {"wm/image_loss", "wm/reward_loss", "wm/discount_loss", "wm/kl", "wm/kl_loss",
                "wm/loss", *(("wm/gate_kl", "wm/gate_loss") if model in GATED else ())}
    assert set(reference) == expected and expected <= set(metrics)
    for name, value in reference.items():
        atol, rtol = TERM_TOLERANCE[name]
        np.testing.assert_allclose(metrics[name], value, rtol=rtol, atol=atol, err_msg=name)


@pytest.mark.parametrize("model", UPDATE_MODELS)
def test_bfloat16_update_runs_every_matmul_in_bfloat16(model):
    text = _update(model, "bfloat16")[-1]
    dots = [line for line in text.splitlines() if "stablehlo.dot_general" in line]
    assert dots and all(BF16_DOT.search(line) for line in dots), \
        [line for line in dots if not BF16_DOT.search(line)][:3]


@pytest.mark.parametrize("model", GATED)
def test_bfloat16_gates_are_exactly_zero_or_one(model):
    """The posterior states' straight-through gate samples (and the states) stay float32 0/1."""
    agent, batch, state = _setup(model, "bfloat16")
    wm = agent.world_model
    observe = jax.jit(lambda params, seq, key: wm.observe(params, seq, key)[0])
    posts = observe(state.params["wm"], jax.tree.map(lambda x: x[0], batch),
                    jax.random.PRNGKey(2))
    assert posts.gate.dtype == jnp.float32 and _float32_leaves(posts)
    assert np.isin(np.asarray(posts.gate), [0.0, 1.0]).all()
    assert 0 < np.asarray(posts.gate).mean() < 1
