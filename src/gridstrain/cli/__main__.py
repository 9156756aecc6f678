"""``python -m gridstrain.cli``: the same as the ``gridstrain`` command."""

from . import entry, started_by_dash_m

entry(own_process=started_by_dash_m())
