"""``python -m gridstrain``: the same as the ``gridstrain`` command."""

import sys

from .cli import main

sys.exit(main())
