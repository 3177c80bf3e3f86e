"""Messages built through their rosidl slots, without the generated constructors' per-field checks.

A generated message class keeps each field in a slot ``_<field>`` plus ``_check_fields`` (whether the setters
check types, from ``ROS_PYTHON_CHECK_FIELDS``). :func:`bare` makes an instance with no field set, for the
caller to fill every slot with a value of the field's type; :func:`check_layout`, called at import for each
class so filled, refuses a layout other than that (a different rosidl generator) with one line.
"""

from __future__ import annotations

from builtin_interfaces.msg import Time

CHECK_FIELDS = Time()._check_fields
"""What the generated constructors store in ``_check_fields``."""

_new = object.__new__


def check_layout(cls: type) -> None:
    """One slot ``_<field>`` per field plus ``_check_fields``, or ImportError."""
    expected = {"_" + name for name in cls.get_fields_and_field_types()} | {"_check_fields"}
    if set(cls.__slots__) != expected:
        raise ImportError(f"{cls.__module__}.{cls.__name__}: unexpected generated message layout {cls.__slots__}")


def bare(cls: type):
    """An instance of a message class whose layout :func:`check_layout` accepted, its field slots unset."""
    msg = _new(cls)
    msg._check_fields = CHECK_FIELDS
    return msg
