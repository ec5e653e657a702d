"""A griffe extension for the API pages (mkdocs.yml, mkdocstrings ``extensions``): the docstrings use
Sphinx roles (``:class:`SceneError```, ``:meth:`~FrameWriter.close```), which Markdown would show
verbatim; they are rendered as code (``SceneError``, ``close``). The sources are not changed."""

from __future__ import annotations

import re

import griffe

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|attr|data|exc|obj):`(~?)([^`]+)`")


def _code(match):
    tilde, target = match.groups()
    return f"`{target.rsplit('.', 1)[-1] if tilde else target}`"


class SphinxRoles(griffe.Extension):
    def on_instance(self, *, obj, **kwargs):
        if obj.docstring is not None:
            obj.docstring.value = ROLE.sub(_code, obj.docstring.value)
