"""The MJX family's own options (``env.flicker``, ``env.hide``, ``env.show_keys``,
``env.show_steps``, ``env.noise_dims``, ``env.noise_scale``: the partially observed and noisy
variants of :mod:`vsgjax.envs.mjx.variants`) and their checks.

:func:`check` is the family's ``check`` in the task registry (:mod:`vsgjax.registry.tasks`):
:func:`vsgjax.config.check_config` runs it on every ``mjx_`` config, before anything is built.
The checks that need the task's observation keys (a hidden key the task does not observe) run
where the task is built (:class:`~vsgjax.envs.mjx.variants.VariantTask`); the numeric ranges
are the config's (:data:`vsgjax.config.checks.RANGES`).
"""

from __future__ import annotations

from vsgjax.config.schema import ConfigError


def check(config) -> None:
    """Raise ConfigError for ``env.show_keys`` without ``env.show_steps`` or the reverse."""
    env = config.env
    if env.show_keys.strip() and env.show_steps < 1:
        raise ConfigError(f"env.show_steps={env.show_steps} with env.show_keys="
                          f"{env.show_keys!r}; valid: >= 1 (the agent steps the keys are shown, "
                          "the reset observation being step 0)")
    if env.show_steps and not env.show_keys.strip():
        raise ConfigError(f"env.show_steps={env.show_steps} without env.show_keys; valid: "
                          "env.show_steps=0, or env.show_keys=<comma-separated observation keys>")
