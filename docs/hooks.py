"""MkDocs hooks (``hooks:`` in mkdocs.yml).

The scene reference (``scene-reference.md``) is generated from the scene schema at build time: when
``warpsph.scene.reference_markdown()`` exists, its Markdown (every key with type, unit, default, range and
meaning) replaces the page; otherwise the page's own text, which says so, stays.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCENE_REFERENCE = "scene-reference.md"


def scene_reference():
    """The generated page, or None when the schema has no ``reference_markdown``."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))  # the checkout's warpsph, also without an installed one
    import warpsph.scene

    if not hasattr(warpsph.scene, "reference_markdown"):
        return None
    text = warpsph.scene.reference_markdown()
    if not text.lstrip().startswith("# "):
        text = "# Scene reference\n\n" + text
    return text


def on_page_markdown(markdown, page, config, files, **kwargs):
    if page.file.src_uri == SCENE_REFERENCE:
        generated = scene_reference()
        if generated is not None:
            return generated
    return markdown
