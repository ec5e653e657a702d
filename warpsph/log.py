"""Logging: warpsph's modules log to ``logging.getLogger(__name__)``, under the ``warpsph`` logger.

The package logger has only a :class:`logging.NullHandler`, so a program that imports warpsph
decides what is shown. The command line calls :func:`configure`, which shows the records on
stderr as ``warpsph: error: ...``, ``warpsph: warning: ...`` and plain info lines.

Warp's own messages (its start-up banner and a line per kernel module loaded, on stdout) are off too:
when Warp is imported after warpsph (or at ``import warpsph`` when it already was), :func:`quiet_warp`
sets ``warp.config.log_level`` to warnings, unless the program chose another level or shows warpsph's
debug records (e.g. ``logging.basicConfig(level=logging.DEBUG)``). A program that wants Warp's lines sets
``wp.config.log_level = wp.LOG_INFO`` after importing warpsph.
"""

from __future__ import annotations

import importlib.abc
import logging
import sys
import warnings
from .errors import SceneError

LOGGER = "warpsph"
QUIET, NORMAL, VERBOSE = -1, 0, 1
LEVELS = {QUIET: logging.WARNING, NORMAL: logging.INFO, VERBOSE: logging.DEBUG}
PLAIN = {"prefix": "warpsph: "}  # ``extra=PLAIN``: "warpsph: message" whatever the level


class Formatter(logging.Formatter):
    """A record's message after a prefix: its ``prefix`` attribute when it has one, else
    ``warpsph: error: `` (ERROR and above), ``warpsph: warning: `` (WARNING), ``debug: `` (DEBUG),
    none (INFO)."""

    def format(self, record):
        prefix = getattr(record, "prefix", None)
        if prefix is None:
            prefix = ("warpsph: error: " if record.levelno >= logging.ERROR else
                      "warpsph: warning: " if record.levelno >= logging.WARNING else
                      "" if record.levelno >= logging.INFO else "debug: ")
        text = prefix + record.getMessage()
        if record.exc_info:
            text += "\n" + self.formatException(record.exc_info)
        return text


class StderrHandler(logging.StreamHandler):
    """Writes to ``sys.stderr`` as it is when a record comes (a test's capture, or rich's redirect
    while a progress bar is shown)."""

    def __init__(self):
        super().__init__()

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


def verbosity(quiet=0, verbose=0):
    """The verbosity of the command line's ``-q`` / ``-v`` counts: QUIET, NORMAL or VERBOSE."""
    return max(QUIET, min(VERBOSE, int(verbose or 0) - int(quiet or 0)))


FILE_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


class LogFileHandler(logging.FileHandler):
    """Appends the records to a log file (``--log FILE``), each with its time, level and logger."""


def file_handler(path):
    """A :class:`LogFileHandler` appending to ``path`` (missing folders made); a :class:`SceneError` naming
    ``--log`` and the file when it cannot be written."""
    from pathlib import Path

    path = Path(path)
    if not str(path) or path.is_dir():
        raise SceneError(path, "--log", "is a directory; --log names the file to append the log to")
    try:
        path.absolute().parent.mkdir(parents=True, exist_ok=True)
        handler = LogFileHandler(path, mode="a", encoding="utf-8")
    except OSError as exc:
        raise SceneError(path, "--log", f"cannot write the log file ({exc.strerror or exc})") from None
    handler.setFormatter(logging.Formatter(FILE_FORMAT))
    return handler


def configure(level=NORMAL, file=None):
    """Shows the ``warpsph`` logger's records from ``level`` (QUIET: warnings and errors, NORMAL:
    info, VERBOSE: debug) on stderr, and Python warnings as ``warpsph: warning: ...`` lines;
    with ``file``, the same records are also appended to that file (timed; see :func:`file_handler`,
    which raises before anything changes). Replaces an earlier :func:`configure`; returns a function
    that undoes it."""
    logger = logging.getLogger(LOGGER)
    handlers = [file_handler(file)] if file is not None else []
    for old in [h for h in logger.handlers if isinstance(h, (StderrHandler, LogFileHandler))]:
        logger.removeHandler(old)
        old.close()
    handlers.insert(0, StderrHandler())
    handlers[0].setFormatter(Formatter())
    saved = logger.level, warnings.showwarning
    for handler in handlers:
        logger.addHandler(handler)
    logger.setLevel(LEVELS[level])
    warnings.showwarning = _show_warning

    def undo():
        for handler in handlers:
            logger.removeHandler(handler)
            handler.close()
        logger.setLevel(saved[0])
        if warnings.showwarning is _show_warning:
            warnings.showwarning = saved[1]

    return undo


def _show_warning(message, category, filename, lineno, file=None, line=None):
    logging.getLogger(LOGGER).warning("%s", message)


def enabled(level):
    """Whether the ``warpsph`` logger passes records of ``level`` (a logging level)."""
    return logging.getLogger(LOGGER).isEnabledFor(level)


def quiet_warp(wp):
    """Warp's log level at warnings (no banner, no module-load lines on stdout) when it is still Warp's
    default and warpsph's debug records are not shown; ``wp`` is the ``warp`` module."""
    if wp.config.log_level == wp.LOG_INFO and not enabled(logging.DEBUG):
        wp.config.log_level = wp.LOG_WARNING


class _QuietWarpLoader(importlib.abc.Loader):
    """Warp's own loader, then :func:`quiet_warp` on the imported package."""

    def __init__(self, loader, finder):
        self.loader, self.finder = loader, finder

    def __getattr__(self, name):
        return getattr(self.loader, name)

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module):
        module.__loader__ = module.__spec__.loader = self.loader
        self.loader.exec_module(module)
        if self.finder in sys.meta_path:
            sys.meta_path.remove(self.finder)
        quiet_warp(module)


class _QuietWarpFinder(importlib.abc.MetaPathFinder):
    """Finds the ``warp`` package as the other finders do, with a loader that quiets it once imported."""

    def find_spec(self, name, path=None, target=None):
        if name != "warp":
            return None
        for finder in sys.meta_path:
            spec = finder.find_spec(name, path, target) if finder is not self and hasattr(finder, "find_spec") else None
            if spec is not None:
                if spec.loader is not None:
                    spec.loader = _QuietWarpLoader(spec.loader, self)
                return spec
        return None


def quiet_warp_on_import():
    """:func:`quiet_warp` now when Warp is imported, else right after its import (whoever imports it)."""
    if "warp" in sys.modules:
        quiet_warp(sys.modules["warp"])
    elif not any(isinstance(f, _QuietWarpFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _QuietWarpFinder())
