"""Architecture rules of the library, checked on its source.

Objects own their private state: no module writes another object's ``_private`` attribute (``other._x = ...``,
``other._x[...] = ...``, ``other._x += ...`` or ``setattr(other, "_x", ...)``); state shared with compiled code is
handed over through public views (``Sensor.arrays``, ``Observer.arrays``) and reported back through public
methods. Nothing replaces an environment's observation function (``_get_obs``): the sensed observation is the
environment's own function evaluated on scratch data.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import smo_gym

SOURCES = sorted(Path(smo_gym.__file__).parent.rglob("*.py"))


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _stored_attributes(target: ast.expr):
    """The attribute nodes a store into ``target`` writes through: ``a.b._c = ``, ``a._b[i] = ``, ``a._b.c = ``."""
    node = target
    while isinstance(node, (ast.Subscript, ast.Attribute, ast.Starred)):
        if isinstance(node, ast.Attribute):
            yield node
        node = node.value


def _owner_is_self(attribute: ast.Attribute) -> bool:
    """``self._x`` or ``cls._x``: the object writes its own state."""
    return isinstance(attribute.value, ast.Name) and attribute.value.id in ("self", "cls")


def cross_object_writes(source: str) -> list[tuple[int, str]]:
    """``(line, text)`` of every write into another object's private attribute, and every ``_get_obs`` store."""
    found = []
    for node in ast.walk(ast.parse(source)):
        targets = []
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
            targets = [node.target]
        elif isinstance(node, ast.Delete):
            targets = node.targets
        for target in targets:
            for element in target.elts if isinstance(target, (ast.Tuple, ast.List)) else [target]:
                for attribute in _stored_attributes(element):
                    if attribute.attr == "_get_obs" or (_private(attribute.attr) and not _owner_is_self(attribute)):
                        found.append((node.lineno, ast.unparse(element)))
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in ("setattr", "delattr")
            and len(node.args) >= 2
            and isinstance(node.args[1], ast.Constant)
            and isinstance(node.args[1].value, str)
            and (node.args[1].value == "_get_obs" or _private(node.args[1].value))
            and not (isinstance(node.args[0], ast.Name) and node.args[0].id in ("self", "cls"))
        ):
            found.append((node.lineno, ast.unparse(node)))
    return found


@pytest.mark.parametrize(
    "code",
    [
        "other._state = x",
        "other._state[0] = x",
        "self.sensor._t += 1",
        "a.b._c.d = 1",
        "env._get_obs = f",
        "self._get_obs = f",
        "setattr(env, '_step', f)",
        "x, other._y = 1, 2",
        "del other._cache",
    ],
)
def test_the_rule_catches_a_write(code):
    assert cross_object_writes(code), code


@pytest.mark.parametrize(
    "code",
    ["self._state = x", "self._scratch.time = 1.0", "other.state[0] = x", "cls._registry = {}", "x._y == 1"],
)
def test_the_rule_allows_own_state_and_public_attributes(code):
    assert not cross_object_writes(code), code


def test_no_private_cross_object_writes_in_the_library():
    offenders = [
        f"{path.relative_to(path.parents[1])}:{line}: {text}"
        for path in SOURCES
        for line, text in cross_object_writes(path.read_text())
    ]
    assert not offenders, "\n".join(offenders)
