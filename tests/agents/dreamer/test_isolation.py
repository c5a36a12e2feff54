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
