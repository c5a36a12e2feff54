"""Model code never imports an environment library (the design's boundary)."""

import subprocess
import sys

ENV_LIBRARIES = ("gymnasium", "pymunk", "dm_control", "mujoco", "ale_py", "bbs", "mcap")
MODEL_MODULES = ("vsgjax.agents.dreamer.cells", "vsgjax.agents.dreamer.dynamics",
                 "vsgjax.agents.dreamer.world_model", "vsgjax.agents.dreamer.behaviour",
                 "vsgjax.agents.dreamer.agent", "vsgjax.agents.dreamer.api", "vsgjax")


def test_model_code_imports_no_environment_library():
    code = (
        "import sys\n"
        f"for m in {MODEL_MODULES!r}: __import__(m)\n"
        f"print(sorted(n for n in {ENV_LIBRARIES!r} if n in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


TRAINING_MODULES = ("vsgjax.train", "vsgjax.agents.dreamer.agent", "vsgjax.loop.host_trainer",
                    "vsgjax.loop.device_trainer", "vsgjax.loop.run_state")
NOTEBOOK_API = "vsgjax.agents.dreamer.api"


def test_training_never_imports_the_notebook_api():
    """The notebook API is a layer over the model: training, open-loop evaluation and gate
    statistics are built on the model layer beneath it."""
    code = (
        "import sys\n"
        f"for m in {TRAINING_MODULES!r}: __import__(m)\n"
        f"print({NOTEBOOK_API!r} in sys.modules, 'vsgjax.agents.dreamer.open_loop' in "
        "sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True"], out.stdout
