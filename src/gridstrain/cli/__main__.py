"""``python -m gridstrain.cli``: the same as the ``gridstrain`` command."""

from . import entry

entry()
