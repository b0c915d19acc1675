"""The checks every public boundary shares: exact types, finite values in documented ranges, exact shapes.

A bool is not a number here (``dt=True`` is not 1 s), a string is not one either (``dt='0.008'`` is not
converted), a complex value is refused rather than cast (NumPy would drop its imaginary part with only a
warning), and a whole number must be whole (``max_steps=2.7`` is not 2). Each error is a ``ValueError``
naming the argument, what it must be and what it got.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np


def real_number(
    name: str, value: Any, low: float = -math.inf, high: float = math.inf, *, low_open: bool = False
) -> float:
    """``value`` as a float: a real number (not a bool, a string or a complex), finite, in ``[low, high]``
    (``(low, high]`` with ``low_open``).

    Raises:
        ValueError: Naming ``name``, the range and the value.
    """
    bracket = "(" if low_open else "["
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number in {bracket}{low:g}, {high:g}], got {value!r}")
    number = float(value)
    below = number <= low if low_open else number < low
    if not math.isfinite(number) or below or number > high:
        raise ValueError(f"{name} must be a finite number in {bracket}{low:g}, {high:g}], got {value!r}")
    return number


def whole_number(name: str, value: Any, low: int, high: int) -> int:
    """``value`` as an int: a whole number (an int, or a float with no fraction; not a bool) in ``[low, high]``.

    Raises:
        ValueError: Naming ``name``, the range and the value.
    """
    whole = isinstance(value, numbers.Integral) or (isinstance(value, numbers.Real) and float(value).is_integer())
    if isinstance(value, (bool, np.bool_)) or not whole or not low <= value <= high:
        raise ValueError(f"{name} must be a whole number in [{low}, {high}], got {value!r}")
    return int(value)


def boolean(name: str, value: Any) -> bool:
    """``value`` as a bool: ``True`` or ``False`` (a NumPy bool too). A string is not a switch (``"no"`` is
    truthy), nor is a number (``1`` or ``0.0``): each is refused rather than read by its truth value.

    Raises:
        ValueError: Naming ``name`` and the value.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def real_array(name: str, value: Any, shape: tuple[int | None, ...] | None = None) -> np.ndarray:
    """``value`` as a float64 array of real, finite numbers, of ``shape`` when given (``None`` entries: any size).

    Raises:
        ValueError: Naming ``name``: not numbers, complex, the wrong shape, or NaN/inf.
    """
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as exc:  # ragged nested sequences
        raise ValueError(f"{name} must be an array of real numbers, got {value!r}") from exc
    if array.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be real numbers, got dtype {array.dtype} ({_short(value)})")
    array = array.astype(np.float64, copy=False)
    if shape is not None and (
        array.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, array.shape))
    ):
        wanted = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name} must have shape {wanted}, got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} must be finite, got NaN or inf ({_short(value)})")
    return array


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."
