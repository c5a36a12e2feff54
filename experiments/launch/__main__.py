import sys

from experiments.launch.cli import main

sys.exit(main())
