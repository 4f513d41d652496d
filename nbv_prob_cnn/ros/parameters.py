"""The parameter framework of the nodes: a node's config is a dataclass whose fields, made with
:func:`param`, are also its ROS parameters; :func:`declare_config` declares them, validates start-up
and run-time values (ranges, choices, a ``check``) and keeps the config up to date."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields
from typing import TYPE_CHECKING, Any, TypeVar

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

ConfigT = TypeVar("ConfigT", bound="DataclassInstance")


def descriptor(
    description: str,
    float_range: tuple[float, float] | None = None,
    int_range: tuple[int, int] | None = None,
    dynamic_typing: bool = False,
    read_only: bool = False,
) -> ParameterDescriptor:
    """A parameter descriptor with a description and, optionally, a numeric range."""
    desc = ParameterDescriptor(description=description, dynamic_typing=dynamic_typing, read_only=read_only)
    if float_range is not None:
        desc.floating_point_range = [FloatingPointRange(from_value=float_range[0], to_value=float_range[1], step=0.0)]
    if int_range is not None:
        desc.integer_range = [IntegerRange(from_value=int_range[0], to_value=int_range[1], step=1)]
    return desc


@dataclass(frozen=True)
class ParamSpec:
    """How a config field is declared as a ROS parameter (see :func:`param`)."""

    description: str
    min_value: float | None = None
    max_value: float | None = None
    choices: tuple | None = None
    dynamic: bool = False
    check: Callable[[Any], None] | None = None
    attribute: str | None = None


def param(
    default: Any,
    description: str,
    *,
    min_value: float | None = None,
    max_value: float | None = None,
    choices: tuple | None = None,
    dynamic: bool = False,
    check: Callable[[Any], None] | None = None,
    attribute: str | None = None,
) -> Any:
    """A field of a node's config dataclass that is also a ROS parameter of the same name.

    Args:
        default: the default value (its type is the parameter's type; lists are copied).
        description: shown by ``ros2 param describe``; ``choices`` are appended.
        min_value, max_value: numeric range (both or none), enforced by rclpy.
        choices: the allowed values.
        dynamic: may change at run time (otherwise read-only after start-up).
        check: raises ``ValueError`` to refuse a value (at start-up and on every set).
        attribute: the node attribute that mirrors the value (default: the field's name).
    """
    spec = ParamSpec(description, min_value, max_value, choices, dynamic, check, attribute)
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata={"param": spec})
    return field(default=default, metadata={"param": spec})


def check_param(name: str, spec: ParamSpec, value: Any) -> None:
    """Raise ``ValueError`` with a reason when ``value`` is not allowed for parameter ``name``."""
    if spec.choices is not None and value not in spec.choices:
        raise ValueError(f"{name}: expected one of {list(spec.choices)}, got {value!r}")
    if spec.check is not None:
        spec.check(value)


def declare_config(node: Node, config_type: type[ConfigT], *, mirror: bool = True) -> ConfigT:
    """Declare one parameter per field of the dataclass ``config_type`` (fields made with
    :func:`param`) and return the config built from their values.

    As ros2/demos ``set_parameters_callback.py``: an on-set callback only validates (choices,
    ``check``, run-time changes of read-only parameters are refused with a reason) and a post-set
    callback applies accepted values to the config (and, with ``mirror``, to the node attribute
    of the same name, or the spec's ``attribute``).

    Raises:
        ValueError: a start-up value is not allowed (the reason names the parameter).
        rclpy.exceptions.ParameterException: wrong type or out of range (checked by rclpy).
    """
    specs: dict[str, ParamSpec] = {}
    values: dict[str, Any] = {}
    for item in fields(config_type):
        spec: ParamSpec = item.metadata["param"]
        default = item.default_factory() if callable(item.default_factory) else item.default
        if default is MISSING:
            raise ValueError(f"{config_type.__name__}.{item.name}: a config field needs a default (make it with param)")
        is_int = isinstance(default, int) and not isinstance(default, bool)
        bounds = None
        if spec.min_value is not None or spec.max_value is not None:
            if spec.min_value is None or spec.max_value is None:
                raise ValueError(f"{item.name}: param() takes both min_value and max_value, or neither")
            bounds = (spec.min_value, spec.max_value)
        text = spec.description + (f" (one of {list(spec.choices)})" if spec.choices else "")
        desc = descriptor(
            text,
            float_range=bounds if (bounds and isinstance(default, float)) else None,
            int_range=(int(bounds[0]), int(bounds[1])) if (bounds and is_int) else None,
            dynamic_typing=isinstance(default, list),  # [0, 1, 2] for a float list, [] for an empty one
            read_only=not spec.dynamic,
        )
        value = node.declare_parameter(item.name, default, desc).value
        if isinstance(default, list):
            value = list(value)
        check_param(item.name, spec, value)
        specs[item.name], values[item.name] = spec, value
    config = config_type(**values)

    def validate(params) -> SetParametersResult:
        for p in params:
            spec = specs.get(p.name)
            if spec is None:
                continue  # not ours (use_sim_time, ...)
            if not spec.dynamic:
                return SetParametersResult(successful=False, reason=f"{p.name} cannot change at run time")
            try:
                check_param(p.name, spec, p.value)
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def apply(params) -> None:
        for p in params:
            if p.name in specs:
                setattr(config, p.name, p.value)
                if mirror:
                    setattr(node, specs[p.name].attribute or p.name, p.value)

    if mirror:
        for name, value in values.items():
            setattr(node, specs[name].attribute or name, value)
    node.add_on_set_parameters_callback(validate)
    node.add_post_set_parameters_callback(apply)
    return config


def positive_seconds(value) -> None:
    """A ``check`` of :func:`param` for durations."""
    if not (isinstance(value, float) and value > 0):
        raise ValueError(f"expected a positive number of seconds, got {value!r}")
