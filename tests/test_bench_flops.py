"""The benchmark's FLOP count: useful work (lax convolutions) below the matmul formulation's."""

import jax
import jax.numpy as jnp

from experiments.bench.bench_world_model import model_flops
from experiments.bench.flops import count_flops
from vsgjax.agents.dreamer.networks import ConvDecoder, ConvEncoder


def test_useful_flops_leave_out_zero_taps_and_match_a_hand_count():
    """The same function counted twice (``jax.make_jaxpr`` caches traces per function)."""
    image = jnp.zeros((2, 64, 64, 3))
    params = ConvEncoder(4).init(jax.random.PRNGKey(0), image)
    flops = model_flops(lambda p, x: ConvEncoder(4).apply(p, x), params, image)
    # stride-2 VALID 4x4 convolutions 64 -> 31 -> 14 -> 6 -> 2, depths 4, 8, 16, 32
    shapes = [(31, 3, 4), (14, 4, 8), (6, 8, 16), (2, 16, 32)]
    expected = sum(2 * 2 * side * side * cin * cout * 16 for side, cin, cout in shapes)
    assert flops["useful"] == expected
    assert flops["matmul_form"] == count_flops(lambda p, x: ConvEncoder(4).apply(p, x), params,
                                               image)

    feat = jnp.zeros((2, 10))
    params = ConvDecoder(4, 3).init(jax.random.PRNGKey(0), feat)
    flops = model_flops(lambda p, f: ConvDecoder(4, 3).apply(p, f), params, feat)
    # the four-phase transposed convolutions multiply zero-padded taps: more than the useful work
    assert flops["matmul_form"] > 1.1 * flops["useful"] > 0
