"""``python -m mmwsim``: the same as the ``mmwsim`` console script."""

import sys

from .cli import main

sys.exit(main())
