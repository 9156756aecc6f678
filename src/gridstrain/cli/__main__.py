"""``python -m gridstrain.cli``: the same as the ``gridstrain`` command."""

import sys

from . import main

sys.exit(main())
