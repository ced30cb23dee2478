"""Declare a node's parameters once, with descriptors and ranges, and validate every change.

Each node gives a table of :class:`ParamSpec` and a ``validate(values) -> config`` function (its
core's parameter dataclass constructor, usually) that raises on bad input. A rejected change
keeps the old value and answers with the validator's message, which names the value and the
allowed range.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterValueException
from rclpy.parameter import Parameter


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

    ``on_change(config)`` is called after every accepted change (and not for rejected ones).
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
        except Exception as exc:  # bad overrides at start-up: say so, fall back to the defaults
            node.get_logger().error(f'{exc}; using the defaults instead')
            for spec in specs:
                node.set_parameters([Parameter(spec.name, value=spec.default)])
            values = {s.name: s.default for s in specs}
            self.config = validate(values)
        self.values = values
        node.add_on_set_parameters_callback(self._check)

    def _declare(self, spec: ParamSpec):
        try:
            return self._node.declare_parameter(spec.name, spec.default, spec.descriptor()).value
        except InvalidParameterValueException as exc:
            self._node.get_logger().error(f'{exc}; keeping the default {spec.default!r}')
            return self._node.declare_parameter(spec.name, spec.default, spec.descriptor(),
                                                ignore_override=True).value

    def _check(self, params: list) -> SetParametersResult:
        values = dict(self.values)
        for p in params:
            if p.name in self._specs:
                values[p.name] = p.value
        try:
            config = self._validate(values)
        except Exception as exc:
            self._node.get_logger().warning(f'parameter change rejected: {exc}')
            return SetParametersResult(successful=False, reason=str(exc))
        self.values, self.config = values, config
        if self._on_change is not None:
            self._on_change(config)
        return SetParametersResult(successful=True)
