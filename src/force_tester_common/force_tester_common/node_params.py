"""Declare a node's parameters once, with descriptors and ranges, and validate every change.

Each node gives a table of :class:`ParamSpec` and a ``validate(values) -> config`` function (its
core's parameter dataclass constructor, usually) that raises on bad input. A bad value given at
start-up (``-p window:=0``, a launch file) stops the node: :class:`ParameterError`, which the
node's main() turns into one line and a non-zero exit, as plain rclpy refuses to start. A
rejected change at run time keeps the old value and answers with the validator's message, which
names the value and the allowed range. Only a change of the validated configuration reaches
``on_change`` (setting ``use_sim_time``, or a value to itself, changes nothing).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException


class ParameterError(ValueError):
    """A node's parameter value at start-up is invalid; the message names it and what was expected."""


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: Any
    description: str
    range: Optional[tuple] = None      # (low, high), inclusive, for int and float parameters
    read_only: bool = False

    def descriptor(self) -> ParameterDescriptor:
        d = ParameterDescriptor(name=self.name, description=self.description, read_only=self.read_only)
        if self.range is not None:
            lo, hi = self.range
            if isinstance(self.default, bool):
                pass
            elif isinstance(self.default, int):
                d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=0)]
            elif isinstance(self.default, float):
                d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
            d.additional_constraints = f'allowed range [{lo}, {hi}]'
        return d


class NodeParams:
    """The declared parameters of one node and the validated configuration built from them.

    ``on_change(config)`` is called after every accepted change of the configuration (not for
    rejected ones, nor for changes that leave the configuration as it was).
    """

    def __init__(self, node, specs: list, validate: Callable[[dict], Any],
                 on_change: Optional[Callable[[Any], None]] = None):
        self._node = node
        self._specs = {s.name: s for s in specs}
        self._validate = validate
        self._on_change = on_change
        values = {}
        for spec in specs:
            values[spec.name] = self._declare(spec)
        try:
            self.config = validate(values)
        except Exception as exc:  # noqa: BLE001 - the validator's own error type, whatever it is
            raise ParameterError(f'{exc}') from None
        self.values = values
        node.add_on_set_parameters_callback(self._check)

    def _declare(self, spec: ParamSpec):
        try:
            return self._node.declare_parameter(spec.name, spec.default, spec.descriptor()).value
        except (InvalidParameterValueException, InvalidParameterTypeException):
            given = getattr(self._node, '_parameter_overrides', {}).get(spec.name)
            value = given.value if given is not None else '?'
            expected = (f'a value in [{spec.range[0]}, {spec.range[1]}]' if spec.range is not None
                        else f'a {type(spec.default).__name__}')
            raise ParameterError(f'parameter {spec.name} {value!r} is invalid; expected {expected}') from None

    def _check(self, params: list) -> SetParametersResult:
        values = dict(self.values)
        for p in params:
            if p.name in self._specs:
                values[p.name] = p.value
        try:
            config = self._validate(values)
        except Exception as exc:  # noqa: BLE001 - a bad value is rejected, the node keeps running
            self._node.get_logger().warning(f'parameter change rejected: {exc}')
            return SetParametersResult(successful=False, reason=str(exc))
        changed = config != self.config
        self.values, self.config = values, config
        if changed and self._on_change is not None:
            self._on_change(config)
        return SetParametersResult(successful=True)
