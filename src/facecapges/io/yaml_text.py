"""YAML from outside (``CLIPS.yaml``, ``train --config``) read with its nesting bounded.

PyYAML's pure-Python reader is quadratic in the nesting of flow collections (its scanner keeps one
possible simple key per open ``[``/``{`` and walks them all at every token: a 3000-deep ``[[[…`` takes
seconds before anything fails) and its composer recurses once per level of any collection. Our files nest
a handful of levels, so :func:`safe_load` refuses a document nested deeper than :data:`MAX_DEPTH` as soon
as the reader gets there: as a ``yaml.MarkedYAMLError`` (:class:`NestingError`) with the line it
happened on, which callers already turn into their one-line ``UserError``.
"""

from __future__ import annotations

from typing import Any

import yaml

MAX_DEPTH = 64  # levels of collections (our files use fewer than 6)


class NestingError(yaml.MarkedYAMLError):
    """The document is nested deeper than :data:`MAX_DEPTH`."""


class _BoundedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that stops at :data:`MAX_DEPTH` open flow collections (scanner) or nested nodes
    (composer, which also bounds block nesting such as ``- - - …``)."""

    def __init__(self, stream) -> None:
        super().__init__(stream)
        self._depth = 0

    def _too_deep(self) -> NestingError:
        return NestingError(problem=f"nested too deeply (more than {MAX_DEPTH} levels)", problem_mark=self.get_mark())

    def fetch_flow_collection_start(self, TokenClass) -> None:
        if self.flow_level >= MAX_DEPTH:
            raise self._too_deep()
        super().fetch_flow_collection_start(TokenClass)

    def compose_node(self, parent, index):
        if self._depth >= MAX_DEPTH:
            raise self._too_deep()
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def safe_load(text: str) -> Any:
    """``yaml.safe_load(text)`` that raises :class:`NestingError` past :data:`MAX_DEPTH` levels."""
    loader = _BoundedLoader(text)
    try:
        return loader.get_single_data()
    finally:
        loader.dispose()
