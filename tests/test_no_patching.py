"""Issue 21, "no test patches the project's own code": a scan of every test source (its AST)
that fails, naming file and line, where a test replaces, wraps or monkeypatches a function,
method, class attribute or module constant of ``cell`` or ``drivers``. A test that needs to
see or steer such a thing uses a seam the code offers (a constructor or function parameter,
a documented setting, an observable attribute or log line); mocking is for what we do not own.

What is flagged:

1. **Patch calls** whose target is ours: ``<monkeypatch>.setattr``/``delattr`` (any receiver
   name, so ``mp`` of ``MonkeyPatch.context()`` too), the ``setattr``/``delattr`` builtins,
   ``patch``, ``patch.object``, ``patch.dict``, ``patch.multiple`` (``unittest.mock``,
   pytest-mock's ``mocker``). The target is ours when it is a dotted string starting with a
   package of ours, or an expression whose name was imported from one. A monkeypatch
   ``setattr`` on a name the scan cannot trace to an import (a local, a fixture) is flagged
   too: patch what we do not own by its import; set the test's own objects directly.
2. **Assignments and ``del``** onto an attribute or item of a name imported from our
   packages (``stations.APPLIED_KEEP = 4``, ``cell.vision.measure.locate = f``, ``Cls.meth = f``).
3. **A function put in place of something ours**: ``x.name = <function>`` where ``name`` is
   defined in ``cell``/``drivers`` (a method, an attribute holding an injected callable) and
   the value is a lambda, a def of the test file, ``functools.partial``, a ``Mock``, or what
   one of our factories returns (a function that returns a nested def or a lambda, such as
   :func:`cell.recipes.motion_check`): the spy ``store.refresh = refresh``.
4. **Private state of ours**: ``x._name = ...`` where ``_name`` is defined in our packages.

Not flagged: the tests' own objects (a fake's hook ``rig.st.on_wait = on_wait``, fields of
a dataclass the test built: ``campaign.model.camera = None``), ``self.``/``cls.`` inside the
tests' classes, and patching what we do not own (``sys.stderr``, ``os``, environment
variables, ``can.bus.time``). The scan infers no types: a callable *object* put in place of
a method, or a mutation through a method call (``module.table.clear()``), is not seen.
"""
from __future__ import annotations

import ast
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
OURS = ("cell", "drivers")

PATCH_CALLS = {"patch", "object", "dict", "multiple"}       # mock.patch and its variants
MOCKS = {"Mock", "MagicMock", "AsyncMock", "NonCallableMock", "create_autospec", "partial",
         "partialmethod", "MethodType"}


@dataclass(frozen=True)
class Finding:
    file: str       #: relative to the repository
    line: int
    target: str     #: the patched target as written (``store.refresh``, ``'cell.x.y'``)
    why: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}: {self.target}: {self.why}"


# ---------------------------------------------------------------------------- what is ours
@dataclass(frozen=True)
class Ours:
    names: frozenset[str]       #: what our packages define: modules, functions, classes, attributes
    factories: frozenset[str]   #: our functions that return a function


def _own_nodes(body: list[ast.AST]):
    """The nodes of one scope: nested function, lambda and class bodies are not entered
    (their def or class node is)."""
    stack = list(body)
    while stack:
        n = stack.pop()
        yield n
        if not isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            stack.extend(ast.iter_child_nodes(n))


def _returns_a_function(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    inner = {n.name for n in _own_nodes(fn.body) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
    return any(isinstance(n, ast.Return) and (isinstance(n.value, ast.Lambda) or
                                              (isinstance(n.value, ast.Name) and n.value.id in inner))
               for n in _own_nodes(fn.body))


def ours_in(roots: list[Path]) -> Ours:
    """What the packages under ``roots`` define: module names; the functions, classes and
    names assigned at module level and in class bodies; every attribute any of their code
    assigns (``self.check = check``). Not their functions' local variables."""
    names, factories = set(), set()

    def scope(body: list[ast.AST]) -> None:
        for n in _own_nodes(body):
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                names.add(n.name)
                if _returns_a_function(n):
                    factories.add(n.name)
            elif isinstance(n, ast.ClassDef):
                names.add(n.name)
                scope(n.body)
            elif isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store):
                names.add(n.id)

    for root in roots:
        for path in root.rglob("*.py"):
            tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
            names.add(path.stem)
            scope(tree.body)
            names.update(n.attr for n in ast.walk(tree)
                         if isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store))
    return Ours(frozenset(names), frozenset(factories))


@lru_cache(maxsize=1)
def ours() -> Ours:
    return ours_in([ROOT / p for p in OURS])


# ---------------------------------------------------------------------------- one test file
def _is_ours(module: str) -> bool:
    return module.split(".")[0] in OURS


def _imports(tree: ast.AST) -> dict[str, set[bool]]:
    """Every name an import binds anywhere in the file -> {whether it is ours}."""
    bound: dict[str, set[bool]] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                name = a.asname or a.name.split(".")[0]
                bound.setdefault(name, set()).add(_is_ours(a.name))
        elif isinstance(node, ast.ImportFrom):
            mine = node.level == 0 and _is_ours(node.module or "")
            for a in node.names:
                bound.setdefault(a.asname or a.name, set()).add(mine)
    return bound


def _root(node: ast.AST) -> str | None:
    """The name an attribute or item chain starts from (``h`` of ``h.cell.runner``)."""
    while isinstance(node, (ast.Attribute, ast.Subscript)):
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def _call_name(func: ast.AST) -> str:
    return func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""


def _text(receiver: ast.AST, attr: object) -> str:
    return f"{ast.unparse(receiver)}.{attr}" if isinstance(attr, str) else ast.unparse(receiver)


@dataclass
class _Scope:
    functions: set[str]     #: names bound to a def or a lambda here
    others: set[str]        #: names bound otherwise (parameters, assignments, imports, loops)


def _scope(body: list[ast.AST], params: set[str] = frozenset()) -> _Scope:
    functions, others = set(), set(params)
    for n in _own_nodes(body):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
            functions.add(n.name)
        elif isinstance(n, ast.Assign) and isinstance(n.value, ast.Lambda):
            functions.update(t.id for t in n.targets if isinstance(t, ast.Name))
        elif isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store):
            others.add(n.id)
        elif isinstance(n, ast.ClassDef):
            others.add(n.name)
        elif isinstance(n, (ast.Import, ast.ImportFrom)):
            others.update((a.asname or a.name).split(".")[0] for a in n.names)
    return _Scope(functions, others - functions)


def _params(fn: ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda) -> set[str]:
    a = fn.args
    return {x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs, a.vararg, a.kwarg) if x is not None}


class _Scan(ast.NodeVisitor):
    def __init__(self, file: str, tree: ast.Module, ours_: Ours):
        self.file, self.ours, self.found = file, ours_, []
        self.imports = _imports(tree)
        self.scopes = [_scope(tree.body)]
        self.in_class = 0
        #: the test file's own functions that return a function (a spy maker)
        self.makers = {n.name for n in ast.walk(tree)
                       if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and _returns_a_function(n)}

    def flag(self, node: ast.AST, target: str, why: str) -> None:
        self.found.append(Finding(self.file, node.lineno, target, why))

    def imported(self, node: ast.AST) -> bool | None:
        """True: its name was imported from our packages; False: from elsewhere; None: not imported."""
        seen = self.imports.get(_root(node) or "")
        return None if not seen else True in seen

    def a_def(self, name: str) -> bool:
        """Whether ``name``, read here, is a def (or lambda) of the test, not a parameter or
        variable of that name."""
        for scope in reversed(self.scopes):
            if name in scope.functions:
                return True
            if name in scope.others:
                return False
        return False

    def function_like(self, value: ast.AST) -> bool:
        if isinstance(value, ast.Lambda):
            return True
        if isinstance(value, ast.Name):
            return self.a_def(value.id)
        if isinstance(value, ast.Call):
            name = _call_name(value.func)
            return (name in MOCKS or (name in self.ours.factories and self.imported(value.func) is True)
                    or (isinstance(value.func, ast.Name) and name in self.makers and self.a_def(name)))
        return False

    # --- scopes; self./cls. inside the tests' own classes are theirs
    def visit_FunctionDef(self, node: ast.FunctionDef | ast.AsyncFunctionDef) -> None:
        for d in node.decorator_list:
            self.visit(d)
        self.scopes.append(_scope(node.body, _params(node)))
        for n in node.body:
            self.visit(n)
        self.scopes.pop()

    visit_AsyncFunctionDef = visit_FunctionDef

    def visit_ClassDef(self, node: ast.ClassDef) -> None:
        self.in_class += 1
        self.generic_visit(node)
        self.in_class -= 1

    # --- assignments and del
    def _target(self, t: ast.AST, value: ast.AST | None) -> None:
        if isinstance(t, (ast.Tuple, ast.List)):
            same = isinstance(value, (ast.Tuple, ast.List)) and len(value.elts) == len(t.elts)
            for k, e in enumerate(t.elts):
                self._target(e, value.elts[k] if same else None)
        elif isinstance(t, ast.Starred):
            self._target(t.value, None)
        elif isinstance(t, (ast.Attribute, ast.Subscript)):
            if self.in_class and isinstance(t.value, ast.Name) and t.value.id in ("self", "cls"):
                return
            attr = t.attr if isinstance(t, ast.Attribute) else None
            self._onto(t, t.value, attr, value, ast.unparse(t))

    def _onto(self, node: ast.AST, receiver: ast.AST, attr: str | None, value: ast.AST | None,
              text: str) -> None:
        if self.imported(receiver) is True:
            self.flag(node, text, "assigns onto a module or class of ours")
        elif attr is not None and attr in self.ours.names:
            if value is not None and self.function_like(value):
                self.flag(node, text, f"puts a test function in place of our {attr!r}")
            elif attr.startswith("_") and not attr.startswith("__"):
                self.flag(node, text, f"writes our private {attr!r}")

    def visit_Assign(self, node: ast.Assign) -> None:
        for t in node.targets:
            self._target(t, node.value)
        self.generic_visit(node)

    def visit_AnnAssign(self, node: ast.AnnAssign) -> None:
        self._target(node.target, node.value)
        self.generic_visit(node)

    def visit_AugAssign(self, node: ast.AugAssign) -> None:
        self._target(node.target, None)
        self.generic_visit(node)

    def visit_Delete(self, node: ast.Delete) -> None:
        for t in node.targets:
            self._target(t, None)
        self.generic_visit(node)

    # --- patch calls
    def visit_Call(self, node: ast.Call) -> None:
        name, func, args = _call_name(node.func), node.func, node.args
        attr = args[1].value if len(args) > 1 and isinstance(args[1], ast.Constant) else None
        if isinstance(func, ast.Name) and name in ("setattr", "delattr") and len(args) >= 2:
            value = args[2] if len(args) > 2 else None
            if self.imported(args[0]) is True:
                self.flag(node, _text(args[0], attr), "assigns onto a module or class of ours")
            elif isinstance(attr, str):
                self._onto(node, args[0], attr, value, _text(args[0], attr))
        elif isinstance(func, ast.Attribute) and name in ("setattr", "delattr") and args:
            self._patch(node, args, attr, monkeypatch=True)
        elif name in PATCH_CALLS and args and self._is_mock_patch(func):
            self._patch(node, args, attr, monkeypatch=False)
        self.generic_visit(node)

    @staticmethod
    def _is_mock_patch(func: ast.AST) -> bool:
        text = ast.unparse(func)
        return text == "patch" or text.endswith(".patch") or ".patch." in text or text.startswith("patch.")

    def _patch(self, node: ast.Call, args: list[ast.AST], attr: object, monkeypatch: bool) -> None:
        first = args[0]
        if isinstance(first, ast.Constant) and isinstance(first.value, str):
            if _is_ours(first.value):
                self.flag(node, repr(first.value), "patches a module of ours by name")
            return
        whose = self.imported(first)
        if whose is True:
            self.flag(node, _text(first, attr), "patches a module, class or object of ours")
        elif whose is None and monkeypatch:
            self.flag(node, _text(first, attr), "monkeypatches an object not traced to an import: "
                      "patch what we do not own by its import; set the test's own objects directly")


def scan_source(source: str, file: str, ours_: Ours | None = None) -> list[Finding]:
    """The patches of our code in one test file's ``source``."""
    tree = ast.parse(source, file)
    s = _Scan(file, tree, ours_ or ours())
    s.visit(tree)
    return s.found


def scan_tests() -> list[Finding]:
    found = []
    for path in sorted(TESTS.rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        found += scan_source(path.read_text(encoding="utf-8"), rel)
    return found


# ---------------------------------------------------------------------------- the rule
def test_no_test_patches_our_code():
    found = scan_tests()
    assert not found, ("tests patch the project's own code (issue 21); give the code a seam "
                       "instead:\n" + "\n".join(map(str, found)))


# ---------------------------------------------------------------------------- the scan itself
OURS_FOR_TESTS = Ours(frozenset({"refresh", "_commit", "_state", "scene", "check", "camera", "locate",
                                 "APPLIED_KEEP", "motion_check", "tool", "clock"}),
                      frozenset({"motion_check"}))


def _flags(source: str) -> list[tuple[int, str]]:
    return [(f.line, f.target) for f in scan_source(source, "t.py", OURS_FOR_TESTS)]


@pytest.mark.parametrize("source, target", [
    ("import drivers.stations.sim as st\ndef t(monkeypatch):\n    monkeypatch.setattr(st, 'APPLIED_KEEP', 4)",
     "st.APPLIED_KEEP"),
    ("def t(monkeypatch):\n    from drivers.plc import memory\n    monkeypatch.setattr(memory, '_state', {})",
     "memory._state"),
    ("def t(monkeypatch):\n    monkeypatch.setattr('cell.vision.measure.locate', None)", "'cell.vision.measure.locate'"),
    ("import cell.vision.measure\ndef t():\n    cell.vision.measure.locate = None", "cell.vision.measure.locate"),
    ("from cell.sim.plc import SimPlc\ndef t(mp):\n    mp.setattr(SimPlc, 'run_cycle', f)", "SimPlc.run_cycle"),
    ("from unittest import mock\nfrom cell import effects as fx\ndef t():\n    with mock.patch.object(fx, 'g'):\n"
     "        pass", "fx.g"),
    ("from unittest.mock import patch\n@patch('drivers.plc.memory.maybe_trim')\ndef t(m):\n    pass",
     "'drivers.plc.memory.maybe_trim'"),
    ("def t(h):\n    store = h.cell.recipes\n    def refresh():\n        pass\n    store.refresh = refresh",
     "store.refresh"),
    ("def t(cam):\n    cam.scene = lambda: []", "cam.scene"),
    ("def t(store):\n    store._commit = audit", "store._commit"),
    ("from cell.recipes import motion_check\ndef t(store):\n    store.check = motion_check(False, [])",
     "store.check"),
    ("def t(store):\n    setattr(store, 'refresh', lambda: [])", "store.refresh"),
    ("def spy(f):\n    def w(*a):\n        return f(*a)\n    return w\n\n\ndef t(store):\n"
     "    store.refresh = spy(store.refresh)", "store.refresh"),
    ("from unittest.mock import MagicMock\ndef t(store):\n    store.refresh = MagicMock()", "store.refresh"),
    ("import drivers.stations.sim_bus as canbus\ndef t():\n    canbus._wires['x'] = None", "canbus._wires['x']"),
    ("def t(monkeypatch, rig):\n    monkeypatch.setattr(rig.runner, 'anything', 1)", "rig.runner.anything"),
])
def test_the_scan_flags_a_patch(source, target):
    assert [t for _, t in _flags(source)] == [target]


@pytest.mark.parametrize("source", [
    "import sys\ndef t(monkeypatch):\n    monkeypatch.setattr(sys, 'stderr', None)",
    "def t(monkeypatch):\n    monkeypatch.setattr('can.bus.time', lambda: 0.0)",
    "import os\ndef t(monkeypatch):\n    monkeypatch.setattr(os, 'read', lambda fd, n: b'')",
    "def t(monkeypatch):\n    monkeypatch.setenv('CELL_PROGRESS', '1')\n    monkeypatch.chdir('/')",
    "def t(rig):\n    def on_wait(n):\n        pass\n    rig.st.on_wait = on_wait",            # a fake's hook
    "def t(c):\n    c.model.camera = None\n    c.points = None",                         # the test's data
    "def t(plan):\n    plan.segment_s = 1.0",                                            # not a function
    "class Fake:\n    def __init__(self):\n        self._commit = lambda c: None\n        self.refresh = None",
    "def t(disk):\n    disk.full = True",
    "def clock():\n    return 1\n\n\ndef t(cam, clock):\n    cam.clock = clock",        # a fixture's value
    "from cell.x import Thing\ndef t():\n    thing = Thing()\n    thing.camera = None",   # data
])
def test_the_scan_leaves_the_tests_own_objects_and_what_we_do_not_own(source):
    assert _flags(source) == []


def test_the_scan_names_the_line():
    assert _flags("import cell.x as x\n\n\ndef t():\n    x.CONST = 4\n") == [(5, "x.CONST")]


def test_ours_are_read_from_the_packages():
    o = ours()
    assert {"refresh", "_commit", "APPLIED_KEEP", "locate", "maybe_trim"} <= o.names
    assert "motion_check" in o.factories and "refresh" not in o.factories
