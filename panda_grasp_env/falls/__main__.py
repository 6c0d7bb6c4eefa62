"""``python -m panda_grasp_env.falls --out data/falls --sequences 2000``: record a falling-tower dataset."""

import sys

from panda_grasp_env.falls.recorder import main

sys.exit(main())
