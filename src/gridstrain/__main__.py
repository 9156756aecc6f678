"""``python -m gridstrain``: the same as the ``gridstrain`` command."""

from .cli import entry, started_by_dash_m

entry(own_process=started_by_dash_m())
