"""What each node offers, read from its code without starting it: the parameters from its config
dataclass (:func:`~nbv_prob_cnn.ros.parameters.param` fields) and its topics, services and actions
from the ``create_publisher`` / ``create_subscription`` / ``create_service`` / ``create_client`` /
``ActionServer`` / ``ActionClient`` (``LockedActionClient``) calls of its module.

``nbv node NAME --help`` prints one node; ``nbv docs nodes --out docs/nodes.md`` writes the
reference page (a test fails when that page is stale).
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import re
import sys
import textwrap
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from nbv_prob_cnn.ros import NODES
from nbv_prob_cnn.ros.parameters import ParamSpec

_CALLS = {
    "create_publisher": ("topic", "publishes"),
    "create_subscription": ("topic", "subscribes"),
    "create_service": ("service", "serves"),
    "create_client": ("service", "calls"),
    "ActionServer": ("action", "serves"),
    "ActionClient": ("action", "calls"),
    "LockedActionClient": ("action", "calls"),  # nbv_prob_cnn.ros.action_client
}


@dataclass(frozen=True)
class ParamDoc:
    """One parameter: its name, type, default, allowed values and description."""

    name: str
    type: str
    default: Any
    allowed: str
    dynamic: bool
    description: str


@dataclass(frozen=True)
class InterfaceDoc:
    """One topic, service or action of a node (``name`` absolute, as with no namespace)."""

    kind: str  # topic, service, action
    direction: str  # publishes, subscribes, serves, calls
    name: str
    type: str
    qos: str
    condition: str


def node_module(name: str) -> ModuleType:
    """The module of node ``name``.

    Raises:
        ValueError: not one of :data:`~nbv_prob_cnn.ros.NODES`.
    """
    if name not in NODES:
        raise ValueError(f"unknown node {name!r}; available: {', '.join(sorted(NODES))}")
    return importlib.import_module(f"nbv_prob_cnn.ros.{name}")


def config_class(module: ModuleType) -> type:
    """The config dataclass the node declares its parameters from (the dataclass of the module, or
    of its ``<module>_config`` companion, whose fields are all
    :func:`~nbv_prob_cnn.ros.parameters.param` fields, named ``...Config``)."""
    found = [
        obj
        for obj in vars(module).values()
        if inspect.isclass(obj) and dataclasses.is_dataclass(obj) and obj.__name__.endswith("Config")
        and obj.__module__ in (module.__name__, f"{module.__name__}_config")
        and all("param" in f.metadata for f in dataclasses.fields(obj))
    ]  # fmt: skip
    if len(found) != 1:
        raise ValueError(f"{module.__name__}: expected one config dataclass, found {[c.__name__ for c in found]}")
    return found[0]


def parameters(name: str) -> list[ParamDoc]:
    """The parameters of node ``name`` in declaration order."""
    rows = []
    for item in dataclasses.fields(config_class(node_module(name))):
        spec: ParamSpec = item.metadata["param"]
        default = item.default if item.default is not dataclasses.MISSING else item.default_factory()  # type: ignore[misc,operator]
        allowed = ""
        if spec.choices is not None:
            allowed = "one of " + ", ".join(f"`{c}`" for c in spec.choices)
        elif spec.min_value is not None:
            allowed = f"[{spec.min_value:g}, {spec.max_value:g}]"
        rows.append(ParamDoc(item.name, type(default).__name__, default, allowed, spec.dynamic, spec.description))
    return rows


def _profile_text(profile: Any) -> str:
    """``reliable, transient local, depth 1`` of an rclpy ``QoSProfile``."""
    reliability = profile.reliability.name.lower().replace("_", " ")
    durability = profile.durability.name.lower().replace("_", " ")
    return f"{reliability}, {durability}, depth {profile.depth}"


def _qos_text(expr: ast.expr | None, module: ModuleType, assigned: dict[str, ast.expr]) -> str:
    if expr is None:
        return ""
    if isinstance(expr, ast.Name) and expr.id in assigned:
        expr = assigned[expr.id]
    if isinstance(expr, ast.IfExp):
        test = re.sub(r"\b(?:self\.config|self|cfg)\.", "", ast.unparse(expr.test))
        body, orelse = _qos_text(expr.body, module, assigned), _qos_text(expr.orelse, module, assigned)
        return f"{body} with {test}, else {orelse}"
    if isinstance(expr, ast.Name) and expr.id == "GRID_QOS":
        return "reliable, transient local, depth 1 (late joiners get the last grid)"
    try:
        value = eval(compile(ast.Expression(expr), module.__name__, "eval"), vars(module))  # noqa: S307
    except Exception:  # a run-time value
        value = None
    if isinstance(value, int):
        return f"reliable, volatile, depth {value}"
    if value is not None and hasattr(value, "reliability") and hasattr(value, "durability"):
        return _profile_text(value)
    if isinstance(expr, ast.Call):
        called = ast.unparse(expr.func)
        if called == "subscription_qos":
            return "volatile; reliability from `qos_reliability` (best_effort = SENSOR_DATA)"
        if called == "QoSProfile":
            words = {k.arg: ast.unparse(k.value) for k in expr.keywords}
            reliability = words.get("reliability", "RELIABLE").split(".")[-1].lower().replace("_", " ")
            durability = words.get("durability", "VOLATILE").split(".")[-1].lower().replace("_", " ")
            depth = words.get("depth", "10")
            depth = "`queue_size`" if "queue_size" in depth else depth
            return f"{reliability}, {durability}, depth {depth}"
    return f"`{ast.unparse(expr)}`"


def _name_text(expr: ast.expr, module: ModuleType) -> str:
    try:
        value = eval(compile(ast.Expression(expr), module.__name__, "eval"), vars(module))  # noqa: S307
    except Exception:  # a loop variable or another run-time value
        text = ast.unparse(expr)
        attribute = re.fullmatch(_CONFIG_PREFIX[2:] + r"(\w+)", text)
        if attribute:
            return f"(parameter {attribute.group(1)})"
        return "(per topic)" if "topic" in text else f"(from {text})"
    return "/" + str(value).lstrip("/")


#: Prefixes of the node's config in conditions (``self.config.use_arm`` -> ``use_arm``).
_CONFIG_PREFIX = r"\b(?:self\.config|self\._params|self|cfg|params)\."


def _optional_helpers(tree: ast.AST) -> dict[str, str]:
    """The condition under which an attribute is not None: ``self._x = Helper(...) if COND else
    None`` -> ``{"self._x": COND}``, and likewise for an attribute whose every other value is set
    inside ``if COND:`` (``self._arm = ArmPlanningSetup(...)`` under ``if self.use_arm:``)."""
    parents = {child: parent for parent in ast.walk(tree) for child in ast.iter_child_nodes(parent)}
    found: dict[str, str] = {}
    conditions: dict[str, set[str]] = {}
    for node in ast.walk(tree):
        if not isinstance(node, (ast.Assign, ast.AnnAssign)) or node.value is None:
            continue
        targets = node.targets if isinstance(node, ast.Assign) else [node.target]
        if len(targets) != 1 or not isinstance(targets[0], ast.Attribute):
            continue
        target, value = ast.unparse(targets[0]), node.value
        if isinstance(value, ast.Constant) and value.value is None:
            continue
        if isinstance(value, ast.IfExp) and isinstance(value.orelse, ast.Constant) and value.orelse.value is None:
            found[target] = ast.unparse(value.test)
        else:
            conditions.setdefault(target, set()).add(_condition(node, parents, raw=True))
    for target, tests in conditions.items():
        if target not in found and len(tests) == 1 and "" not in tests:
            found[target] = tests.pop()
    return found


def _grouped(condition: str) -> str:
    """``condition`` in parentheses when it is an ``and`` / ``or`` (to stand inside another)."""
    try:
        grouped = isinstance(ast.parse(condition, mode="eval").body, ast.BoolOp)
    except SyntaxError:
        grouped = True
    return f"({condition})" if grouped else condition


def _simplified(condition: str) -> str:
    """Duplicate conjuncts, and a conjunct ``a or b`` next to ``a``, dropped: ``a and (a or b)`` -> ``a``."""
    try:
        tree = ast.parse(condition, mode="eval").body
    except SyntaxError:
        return condition
    conjuncts = tree.values if isinstance(tree, ast.BoolOp) and isinstance(tree.op, ast.And) else [tree]
    texts = [ast.unparse(c) for c in conjuncts]
    kept: list[ast.expr] = []
    for conjunct, text in zip(conjuncts, texts, strict=True):
        absorbed = (
            isinstance(conjunct, ast.BoolOp)
            and isinstance(conjunct.op, ast.Or)
            and any(ast.unparse(v) in texts for v in conjunct.values)
        )
        if not absorbed and text not in [ast.unparse(k) for k in kept]:
            kept.append(conjunct)
    if len(kept) == len(conjuncts):
        return condition
    return ast.unparse(kept[0] if len(kept) == 1 else ast.BoolOp(ast.And(), kept))


def _condition(
    node: ast.AST, parents: dict[ast.AST, ast.AST], optional: dict[str, str] | None = None, raw: bool = False
) -> str:
    """The conditions of the ``if`` statements and expressions around ``node``, joined by ``and``,
    config prefixes removed (kept with ``raw``) and simplified (:func:`_simplified`)."""
    tests = []
    while node in parents:
        parent = parents[node]
        test = ast.unparse(parent.test) if isinstance(parent, (ast.If, ast.IfExp)) else ""
        for attribute, condition in (optional or {}).items():  # "self._tf is None" -> "not (pose_source == 'tf')"
            test = test.replace(f"{attribute} is None", f"not ({condition})")
            test = test.replace(f"{attribute} is not None", _grouped(condition))
        if isinstance(parent, (ast.If, ast.IfExp)) and node in ([parent.body] if isinstance(parent, ast.IfExp)
                                                                else parent.body):  # fmt: skip
            tests.append(test)
        elif (
            isinstance(parent, ast.If)
            and node in parent.orelse
            or isinstance(parent, ast.IfExp)
            and node is parent.orelse
        ):
            tests.append(f"not ({test})")
        node = parent
    text = " and ".join(reversed(tests))
    return text if raw else _simplified(re.sub(_CONFIG_PREFIX, "", text))


def _helper_class(call: ast.Call, module: ModuleType) -> type | None:
    """The class of a call ``Helper(..., self, ...)`` when ``Helper`` is a class of another module of
    :mod:`nbv_prob_cnn.ros` (it creates interfaces on the node it is given, e.g. ``TfListener``,
    ``JointStateIntake(robot, self, self._streams.node)``)."""
    # the node itself, or its side node for high-rate streams (nbv_prob_cnn.ros.stream_node)
    if not (
        isinstance(call.func, ast.Name) and any(ast.unparse(arg) in ("self", "self._streams.node") for arg in call.args)
    ):
        return None
    obj = vars(module).get(call.func.id)
    if inspect.isclass(obj) and obj.__module__.startswith("nbv_prob_cnn.ros.") and obj.__module__ != module.__name__:
        return obj
    return None


def _scan(source: str, module: ModuleType, outer: str = "") -> list[InterfaceDoc]:
    """The ``create_*`` / action calls of ``source`` (names resolved in ``module``), and those of
    the helper classes it hands the node to; ``outer`` is the condition of the whole source."""
    tree = ast.parse(source)
    parents = {child: parent for parent in ast.walk(tree) for child in ast.iter_child_nodes(parent)}
    assigned: dict[str, ast.expr] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            assigned.setdefault(node.targets[0].id, node.value)
    optional = _optional_helpers(tree)
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        condition = " and ".join(c for c in (outer, _condition(node, parents, optional)) if c)
        helper = _helper_class(node, module)
        if helper is not None:
            found += _scan(textwrap.dedent(inspect.getsource(helper)), sys.modules[helper.__module__], condition)
            continue
        called = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
        if called not in _CALLS:
            continue
        kind, direction = _CALLS[called]
        args = node.args[1:] if kind == "action" else node.args  # ActionServer(self, Type, name)
        if len(args) < 2:
            continue
        qos = args[3] if kind == "topic" and direction == "subscribes" and len(args) > 3 else None
        if kind == "topic" and direction == "publishes":
            qos = args[2] if len(args) > 2 else None
        type_name = ast.unparse(args[0]).split(".")[-1]
        type_name = type_name if re.fullmatch(r"[A-Z]\w*", type_name) else "(per topic)"
        qos_text = _qos_text(qos, module, assigned) if kind == "topic" else ""
        found.append(InterfaceDoc(kind, direction, _name_text(args[1], module), type_name, qos_text, condition))
    return found


def interfaces(name: str) -> list[InterfaceDoc]:
    """The topics, services and actions node ``name`` creates (also through helper classes such as
    the TF listener), sorted by kind, direction and name."""
    module = node_module(name)
    found = _scan(inspect.getsource(module), module)
    order = {"topic": 0, "service": 1, "action": 2}
    return sorted(set(found), key=lambda i: (order[i.kind], i.direction, i.name, i.condition))


def summary(name: str) -> str:
    """The first paragraph of the node module's docstring, without its ``name:`` prefix."""
    text = (node_module(name).__doc__ or "").strip().split("\n\n")[0]
    text = re.sub(r"^(?:Node )?``\w+``:\s*", "", " ".join(text.split()))
    text = re.sub(r"\s*\(SPEC[^)]*\)", "", text)
    return text[:1].upper() + text[1:]


def _value(value: Any) -> str:
    return f'"{value}"' if isinstance(value, str) else repr(value)


def help_text(name: str) -> str:
    """Plain-text help of one node: what it does, its interfaces and its parameters."""
    lines = [f"{name}: {summary(name)}", "", "Interfaces (names with no namespace):"]
    for i in interfaces(name):
        extra = "; ".join(t for t in (i.qos, f"only {i.condition}" if i.condition else "") if t)
        lines.append(f"  {i.direction:10s} {i.kind:7s} {i.name}  [{i.type}]" + (f"  ({extra})" if extra else ""))
    lines += ["", "Parameters (--ros-args -p NAME:=VALUE; * = may change at run time):"]
    for p in parameters(name):
        allowed = f"  {p.allowed}" if p.allowed else ""
        lines.append(f"  {p.name}{'*' if p.dynamic else ''} ({p.type}, default {_value(p.default)}){allowed}")
        lines.append(f"      {p.description}")
    lines += ["", f"Run it: nbv node {name} --ros-args -p NAME:=VALUE ... (or ros2 run nbv_prob_cnn {name})"]
    return "\n".join(lines)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def nodes_markdown() -> str:
    """The page ``docs/nodes.md``: every node's interfaces and parameters."""
    out = [
        "# Nodes: topics, services, actions and parameters",
        "",
        "<!-- Generated by `nbv docs nodes --out docs/nodes.md` from the nodes' code (config dataclasses and",
        "     create_* calls); do not edit by hand: test/ros/test_node_docs.py fails when this page is stale. -->",
        "",
        "Names are shown as they resolve with no namespace; every name is relative, so",
        '`--ros-args -r __ns:=/robot1` moves a whole graph under `/robot1/...`. QoS "depth N" without more',
        "is rclpy's default profile (keep last N, reliable, volatile). Parameters are set with",
        "`--ros-args -p NAME:=VALUE`; those marked *run time* may also change while the node runs",
        "(`ros2 param set`, or a `SetParameters` call); the others are read-only after start-up. A value",
        "outside its range or choices is refused with the reason. `nbv node NAME --help` prints the",
        "same without starting the node.",
        "",
    ]
    for name in NODES:
        out += [f"- [`{name}`](#{name})"]
    for name in NODES:
        out += [
            "",
            f"## {name}",
            "",
            summary(name),
            "",
            "| | kind | name | type | QoS / condition |",
            "|---|---|---|---|---|",
        ]
        for i in interfaces(name):
            extra = "; ".join(t for t in (i.qos, f"only {i.condition}" if i.condition else "") if t)
            shown = i.name if i.name.startswith("(") else f"`{i.name}`"
            typed = i.type if i.type.startswith("(") else f"`{i.type}`"
            out.append(f"| {i.direction} | {i.kind} | {shown} | {typed} | {_cell(extra)} |")
        out += ["", "| parameter | type | default | allowed | run time | description |", "|---|---|---|---|---|---|"]
        for p in parameters(name):
            out.append(f"| `{p.name}` | {p.type} | `{_cell(_value(p.default))}` | {_cell(p.allowed)} | "
                       f"{'yes' if p.dynamic else ''} | {_cell(p.description)} |")  # fmt: skip
    return "\n".join(out) + "\n"
