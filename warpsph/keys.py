"""The scene schema's building blocks: a frozen, strictly validated pydantic dataclass (:func:`schema`) and its fields
(:func:`key`: default, meaning, unit, range), used by the scene (:mod:`warpsph.scene`), the models' and the pressure
solvers' own parameters; apart from the scene so that those plug-ins need not import it."""

from __future__ import annotations

import typing
from typing import Any

from pydantic import ConfigDict, Field
from pydantic.dataclasses import dataclass as pydantic_dataclass

# strict: no coercion ("3" is not a number, 2.0 not an integer, true not 1); an unknown key is an error
CONFIG = ConfigDict(strict=True, extra="forbid", allow_inf_nan=False)


def schema(cls):
    """Class decorator: a frozen, strictly validated pydantic dataclass of the scene schema."""
    return pydantic_dataclass(frozen=True, config=CONFIG)(cls)


def key(default: Any = ..., doc: str = "", unit: typing.Optional[str] = None, **limits):
    """A schema field: its default (``...``: required), what it means, its unit and its range
    (pydantic's gt / ge / lt / le). They go into the JSON Schema (``warpsph schema``) and the docs."""
    return Field(default, description=doc or None, json_schema_extra={"unit": unit} if unit else None, **limits)


MAX_MODEL_VISCOSITY = 1.0  # [m^2/s], 20x the fluid's default: the models' viscosity keys stop there
