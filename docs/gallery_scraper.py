"""A sphinx-gallery image scraper for the figures gridstrain returns.

gridstrain's plotting functions return :class:`matplotlib.figure.Figure` objects
that pyplot does not manage (the library leaves pyplot's global state alone), so
sphinx-gallery's matplotlib scraper, which asks pyplot for its figures, does not see
them. This one picks up every such figure an example holds in a variable, once.
It runs before the matplotlib scraper, which closes pyplot's figures: a figure with
a pyplot manager here is pyplot's, recorded so that it is not taken for one of ours
once closed.
"""

from __future__ import annotations

import weakref

_shown: weakref.WeakSet = weakref.WeakSet()


def library_figures(block, block_vars, gallery_conf):
    """Save the example's new pyplot-free figures; return their reST."""
    from matplotlib.figure import Figure
    from sphinx_gallery.scrapers import figure_rst

    paths = []
    for value in list(block_vars["example_globals"].values()):
        if not isinstance(value, Figure) or value in _shown:
            continue
        _shown.add(value)
        if value.canvas.manager is None:
            path = next(block_vars["image_path_iterator"])
            value.savefig(path)
            paths.append(path)
    return figure_rst(paths, gallery_conf["src_dir"])
