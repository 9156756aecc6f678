"""``python -m gridstrain``: the same as the ``gridstrain`` command."""

from .cli import entry

entry()
