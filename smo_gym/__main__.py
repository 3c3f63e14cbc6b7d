"""``python -m smo_gym``: the ``smo-gym`` command line (:mod:`smo_gym.cli`)."""

import sys

from .cli import main

sys.exit(main())
