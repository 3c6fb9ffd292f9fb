"""``python -m slr_ray.cli``: the same as ``slr-ray``."""

import sys

from . import main

sys.exit(main())
