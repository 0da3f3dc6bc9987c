"""Read ROS 2 XML launch files (the subset FLAAIR's graphs use) into plain data, without ROS.

PyPI carries no `launch`/`launch_ros`, so `bin/flaair launch` reads the files itself; they stay
standard launch files, valid for `ros2 launch` on a full install (tests check them against the
format's schema). The subset:

  <launch>                       root (optional version="...")
  <arg name default|value description/>   a launch argument (value: fixed, not overridable)
  <let name value/>              a launch configuration
  <node pkg exec name namespace> a node, with <param name value/>, <param from="FILE"/> and
                                 <remap from to/> inside
  <group scoped>                 a scope; <push-ros-namespace namespace/> first inside it
  <include file>                 another launch file, with <arg name value/> inside

`if` / `unless` on node, group and include; substitutions $(var NAME), $(env NAME [DEFAULT]),
$(find-pkg-share PACKAGE) and $(dirname) (the launch file's directory). Anything else is refused
by name (`LaunchFileError`), as is a launch argument the files do not declare.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

from flaair_model.checked_files import CheckedFileError, read_bytes

__all__ = [
    "LaunchArgument",
    "LaunchDescription",
    "LaunchFileError",
    "LaunchNode",
    "load",
    "parse_launch_arguments",
]


MAX_INCLUDE_DEPTH = 16


class LaunchFileError(ValueError):
    """A launch file cannot be read: the message names the file, the element and what is wrong."""


@dataclass(frozen=True)
class LaunchArgument:
    """A declared launch argument (`default` None: required)."""

    name: str
    default: str | None
    description: str


@dataclass(frozen=True)
class LaunchNode:
    """One node to start: `bin/flaair run PACKAGE EXECUTABLE --ros-args <ros_args()>`."""

    package: str
    executable: str
    name: str | None  # None: the node's own default name
    namespace: str  # absolute ("/" for the root namespace)
    parameters: tuple[tuple[str, str], ...]  # (name, value as written: YAML, as `-p` reads it)
    parameter_files: tuple[str, ...]
    remaps: tuple[tuple[str, str], ...]

    def ros_args(self) -> list[str]:
        """The node's `--ros-args` words: name, namespace, parameter files, parameters, remaps."""
        words: list[str] = []
        if self.name:
            words += ["-r", f"__node:={self.name}"]
        if self.namespace != "/":
            words += ["-r", f"__ns:={self.namespace}"]
        for path in self.parameter_files:
            words += ["--params-file", path]
        for name, value in self.parameters:
            words += ["-p", f"{name}:={value}"]
        for source, target in self.remaps:
            words += ["-r", f"{source}:={target}"]
        return words


@dataclass(frozen=True)
class LaunchDescription:
    """What a launch file starts, in order, and the launch configurations it ended with."""

    path: Path
    arguments: tuple[LaunchArgument, ...]
    nodes: tuple[LaunchNode, ...]
    configurations: Mapping[str, str]


def parse_launch_arguments(words: list[str]) -> dict[str, str]:
    """`name:=value` words (as `ros2 launch` takes them) as a dict; LaunchFileError otherwise."""
    out = {}
    for word in words:
        name, sep, value = word.partition(":=")
        if not sep or not name:
            raise LaunchFileError(f"launch argument {word!r} is not of the form name:=value")
        out[name] = value
    return out


_ATTRIBUTES = {  # tag -> the attributes it may carry
    "launch": {"version"},
    "arg": {"name", "default", "value", "description"},
    "let": {"name", "value"},
    "node": {"pkg", "exec", "name", "namespace", "output", "if", "unless"},
    "param": {"name", "value", "from"},
    "remap": {"from", "to"},
    "group": {"scoped", "if", "unless"},
    "push-ros-namespace": {"namespace"},
    "push_ros_namespace": {"namespace"},
    "include": {"file", "if", "unless"},
}
_SUBSTITUTION = re.compile(r"\$\(([a-z-]+)((?:\s+[^)\s]+)*)\s*\)")
_TRUE, _FALSE = {"true", "1"}, {"false", "0"}
# ROS 2 name rules (rcl's validators): a token is a letter or '_' then letters, digits, '_'
_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_NAME_RULES = {  # what a node's name, namespace, parameter and remap may be
    "node name": re.compile(_TOKEN),
    "namespace": re.compile(rf"/|(/{_TOKEN})+"),
    "parameter name": re.compile(rf"{_TOKEN}(\.{_TOKEN})*"),
    "remap": re.compile(rf"~?/?({_TOKEN}|\{{{_TOKEN}\}})(/({_TOKEN}|\{{{_TOKEN}\}}))*|~"),
}


def _check_name(kind: str, value: str) -> str | None:
    """Why `value` is not a valid ROS `kind` (None: it is)."""
    if _NAME_RULES[kind].fullmatch(value):
        return None
    return (
        f"{kind} {value!r} is not a valid ROS name (letters, digits and '_', not first a "
        "digit, in '/'-separated parts)"
    )


class _Scope:
    """Launch configurations and the pushed namespace of the elements being read."""

    def __init__(self, configurations: dict[str, str], namespace: str) -> None:
        self.configurations, self.namespace = configurations, namespace

    def child(self) -> _Scope:
        return _Scope(dict(self.configurations), self.namespace)


class _Reader:
    def __init__(
        self, path: Path, find_share: Callable[[str], Path], allow_missing: bool = False
    ) -> None:
        self.path, self.find_share, self.allow_missing = path, find_share, allow_missing
        self.nodes: list[LaunchNode] = []
        self.chain: tuple[Path, ...] = ()  # the files that include this one, and it

    def fail(self, where: str, why: str) -> LaunchFileError:
        return LaunchFileError(f"{self.path}: {where}: {why}")

    def substitute(self, text: str, scope: _Scope, where: str) -> str:
        def one(match: re.Match) -> str:
            kind, words = match.group(1), match.group(2).split()
            if kind == "var" and len(words) == 1:
                if words[0] not in scope.configurations:
                    raise self.fail(
                        where,
                        f"$(var {words[0]}): no launch configuration "
                        f"'{words[0]}' (known: "
                        f"{', '.join(sorted(scope.configurations)) or 'none'})",
                    )
                return scope.configurations[words[0]]
            if kind == "dirname" and not words:
                return str(self.path.parent)
            if kind == "env" and len(words) in (1, 2):
                value = os.environ.get(words[0], words[1] if len(words) == 2 else None)
                if value is None:
                    raise self.fail(where, f"$(env {words[0]}): not set and no default")
                return value
            if kind == "find-pkg-share" and len(words) == 1:
                try:
                    return str(self.find_share(words[0]))
                except LookupError as exc:
                    raise self.fail(where, f"$(find-pkg-share {words[0]}): {exc}") from None
            raise self.fail(
                where,
                f"substitution $({kind} ...) is not supported here (supported: "
                "$(var NAME), $(env NAME [DEFAULT]), $(find-pkg-share PKG), "
                "$(dirname))",
            )

        return _SUBSTITUTION.sub(one, text)

    def attributes(
        self, element: ET.Element, scope: _Scope, where: str, required: tuple[str, ...] = ()
    ) -> dict[str, str]:
        unknown = sorted(set(element.attrib) - _ATTRIBUTES[element.tag])
        if unknown:
            raise self.fail(
                where,
                f"<{element.tag}> has no attribute {', '.join(unknown)} "
                f"(it takes: {', '.join(sorted(_ATTRIBUTES[element.tag]))})",
            )
        missing = [name for name in required if name not in element.attrib]
        if missing:
            raise self.fail(where, f"<{element.tag}> needs {', '.join(missing)}")
        return {k: self.substitute(v, scope, where) for k, v in element.attrib.items()}

    def condition(self, attrs: dict[str, str], where: str) -> bool:
        for key, wanted in (("if", True), ("unless", False)):
            if key in attrs:
                value = attrs[key].strip().lower()
                if value not in _TRUE | _FALSE:
                    raise self.fail(where, f"{key}={attrs[key]!r} is not true/false")
                if (value in _TRUE) != wanted:
                    return False
        return True

    def actions(
        self,
        parent: ET.Element,
        scope: _Scope,
        where: str,
        arguments: list[LaunchArgument],
        given: dict[str, str],
    ) -> None:
        for index, element in enumerate(parent):
            at = f"{where}/{element.tag}[{index}]"
            if element.tag not in _ATTRIBUTES or element.tag in ("launch", "param", "remap"):
                raise self.fail(
                    at,
                    f"unknown or misplaced tag <{element.tag}> (this reader "
                    "takes arg, let, node, group, push-ros-namespace, include)",
                )
            getattr(self, "on_" + element.tag.replace("-", "_"))(
                element, scope, at, arguments, given
            )

    def on_arg(self, element, scope, at, arguments, given) -> None:
        attrs = self.attributes(element, scope, at, ("name",))
        name = attrs["name"]
        arguments.append(LaunchArgument(name, attrs.get("default"), attrs.get("description", "")))
        if "value" in attrs:
            if name in given:
                raise self.fail(at, f"launch argument '{name}' is fixed to {attrs['value']!r}")
            scope.configurations[name] = attrs["value"]
        elif name in given:
            scope.configurations[name] = given[name]
        elif "default" in attrs:
            scope.configurations[name] = attrs["default"]
        elif self.allow_missing:
            scope.configurations[name] = ""
        else:
            raise self.fail(at, f"launch argument '{name}' is required: add {name}:=VALUE")

    def on_let(self, element, scope, at, arguments, given) -> None:
        attrs = self.attributes(element, scope, at, ("name", "value"))
        scope.configurations[attrs["name"]] = attrs["value"]

    def on_push_ros_namespace(self, element, scope, at, arguments, given) -> None:
        scope.namespace = _join(
            scope.namespace, self.attributes(element, scope, at, ("namespace",))["namespace"]
        )

    def on_group(self, element, scope, at, arguments, given) -> None:
        attrs = self.attributes(element, scope, at)
        if self.condition(attrs, at):
            scoped = attrs.get("scoped", "true").lower() not in _FALSE
            self.actions(element, scope.child() if scoped else scope, at, arguments, given)

    def on_node(self, element, scope, at, arguments, given) -> None:
        attrs = self.attributes(element, scope, at, ("pkg", "exec"))
        if not self.condition(attrs, at):
            return
        parameters, files, remaps = [], [], []
        for index, child in enumerate(element):
            where = f"{at}/{child.tag}[{index}]"
            if child.tag == "param":
                values = self.attributes(child, scope, where)
                if "from" in values and not {"name", "value"} & set(values):
                    files.append(values["from"])
                elif {"name", "value"} <= set(values) and "from" not in values:
                    parameters.append((values["name"], values["value"]))
                else:
                    raise self.fail(where, "<param> takes name and value, or from")
            elif child.tag == "remap":
                values = self.attributes(child, scope, where, ("from", "to"))
                remaps.append((values["from"], values["to"]))
            else:
                raise self.fail(
                    where, f"unknown tag <{child.tag}> in <node> (it takes param, remap)"
                )
        namespace = _join(scope.namespace, attrs.get("namespace", ""))
        checked = [("namespace", namespace), ("node name", attrs.get("name") or "node")]
        checked += [("parameter name", name) for name, _ in parameters]
        checked += [("remap", name) for pair in remaps for name in pair]
        for kind, value in checked:  # before any command line is printed or run
            why = _check_name(kind, value)
            if why is not None:
                raise self.fail(at, why)
        self.nodes.append(
            LaunchNode(
                attrs["pkg"],
                attrs["exec"],
                attrs.get("name"),
                namespace,
                tuple(parameters),
                tuple(files),
                tuple(remaps),
            )
        )

    def on_include(self, element, scope, at, arguments, given) -> None:
        attrs = self.attributes(element, scope, at, ("file",))
        if not self.condition(attrs, at):
            return
        passed = {}
        for index, child in enumerate(element):
            where = f"{at}/{child.tag}[{index}]"
            if child.tag != "arg":
                raise self.fail(where, f"unknown tag <{child.tag}> in <include> (it takes arg)")
            values = self.attributes(child, scope, where, ("name", "value"))
            passed[values["name"]] = values["value"]
        path = Path(attrs["file"])
        if not path.is_absolute():
            path = self.path.parent / path
        included = _read(
            path, passed, self.find_share, scope.child(), self.allow_missing, self.chain
        )
        self.nodes.extend(included.nodes)


def _join(namespace: str, more: str) -> str:
    """`more` inside `namespace` (an absolute `more` replaces it); always absolute."""
    if more.startswith("/"):
        return "/" + more.strip("/") if more.strip("/") else "/"
    parts = [p for p in (namespace.strip("/"), more.strip("/")) if p]
    return "/" + "/".join(parts)


def _read(
    path: Path,
    given: Mapping[str, str],
    find_share: Callable[[str], Path],
    scope: _Scope,
    allow_missing: bool = False,
    chain: tuple[Path, ...] = (),
) -> LaunchDescription:
    resolved = Path(os.path.realpath(path))
    if resolved in chain or len(chain) >= MAX_INCLUDE_DEPTH:
        raise LaunchFileError(
            f"{chain[-1]}: includes {path}, which includes it back"
            if resolved in chain
            else f"{path}: launch files included more than {MAX_INCLUDE_DEPTH} deep"
        )
    try:  # a regular file of a bounded size (a directory or a FIFO is no launch file)
        root = ET.fromstring(read_bytes(path, "launch"))
    except CheckedFileError as exc:
        text = str(exc) if os.path.lexists(path) else f"{path}: no such launch file"
        raise LaunchFileError(text) from None
    except ET.ParseError as exc:
        raise LaunchFileError(f"{path}: not well-formed XML: {exc}") from None
    reader = _Reader(path, find_share, allow_missing)
    reader.chain = (*chain, resolved)
    if root.tag != "launch":
        raise reader.fail(root.tag, "the root element must be <launch>")
    reader.attributes(root, scope, "launch")
    arguments: list[LaunchArgument] = []
    reader.actions(root, scope, "launch", arguments, dict(given))
    unknown = sorted(set(given) - {a.name for a in arguments})
    if unknown:
        raise reader.fail(
            "launch",
            f"no launch argument {', '.join(unknown)} (it takes: "
            f"{', '.join(a.name for a in arguments) or 'none'})",
        )
    return LaunchDescription(
        path, tuple(arguments), tuple(reader.nodes), dict(scope.configurations)
    )


def load(
    path: str | Path,
    arguments: Mapping[str, str] | None = None,
    find_share: Callable[[str], Path] | None = None,
    namespace: str = "/",
    allow_missing_arguments: bool = False,
) -> LaunchDescription:
    """Read the launch file at `path` with launch `arguments` (name -> value), inside
    `namespace`. `find_share(package)` resolves $(find-pkg-share) (default: the ament index);
    it raises LookupError for an unknown package. `allow_missing_arguments`: a required argument
    left out reads as "" (to list a file's arguments) instead of an error.
    """
    return _read(
        Path(path),
        dict(arguments or {}),
        find_share or _ament_share,
        _Scope({}, _join("/", namespace)),
        allow_missing_arguments,
    )


def _ament_share(package: str) -> Path:
    try:
        return Path(get_package_share_directory(package))
    except PackageNotFoundError:
        raise LookupError(f"package '{package}' is not installed") from None
