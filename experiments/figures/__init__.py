"""Small illustrative figures of the docs (``docs/figures/``), one module each, each run as
``python -m experiments.figures.<name>``."""
