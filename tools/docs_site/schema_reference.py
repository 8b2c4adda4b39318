"""The fields of our strict configuration files, read from the code that parses them.

Scenarios and host configurations have no schema file: their parsers (`bywire.hil.scenario`,
`bywire.hil.world.spec`, `bywire.hil.world.urban_spec`, `bywire.host.config`) ask a
`bywire.schema.Reader` for each field, with its default and its limits (`r.number("v0_mps",
default=0.0, lo=0.0, hi=70.0)`). This module reads those calls from the parsers' source (the AST, not
a run), following readers through `sub`, through list items (`f"faults[{i}]"`) and into the helper
functions they are handed to, and keeps the `if` that guards a field (`kind == 'estop'`). What a
reference page shows is then what the parser does, and a field added to a parser shows up by itself.
"""

from __future__ import annotations

import ast
import builtins
import importlib
import inspect
import re
from collections.abc import Iterator
from dataclasses import dataclass, field

# Reader methods that read one field, with their positional parameters after the key.
FIELD_METHODS: dict[str, tuple[str, ...]] = {
    "number": ("default", "lo", "hi"),
    "opt_number": ("lo", "hi"),
    "string": ("default", "choices"),
    "boolean": ("default",),
    "profile": (),
    "raw": ("default",),
    "has": (),
}
KIND_NAMES = {
    "number": "number",
    "opt_number": "number or null",
    "string": "string",
    "boolean": "true / false",
    "profile": "number or [[t_s, value], ...]",
    "raw": "value",
    "has": "value",
}
# Calls whose result a limit or default may be evaluated through (nothing with side effects).
_SAFE_CALLS = {"float", "int", "tuple", "sorted", "list"}


@dataclass
class SchemaField:
    """One field of a file: its dotted path (`[]` for any item of a list) and what the parser takes."""

    path: str
    method: str
    default: str = ""
    lo: str = ""
    hi: str = ""
    choices: str = ""
    conditions: list[str] = field(default_factory=list)
    where: str = ""  # module.function of the parser
    has_items: bool = False  # a list whose items are read field by field (`faults[].kind`)
    messages: list[str] = field(default_factory=list)  # what the parser says when it refuses the field

    @property
    def kind(self) -> str:
        if self.method in ("raw", "has"):
            # A value the parser checks itself: its own words for what it expects.
            expected = next((m for m in self.messages if m.startswith("expected ")), "")
            if expected:
                return expected.removeprefix("expected ")
            if self.has_items or self.default in ("[]", "{}"):
                return "mapping" if self.default == "{}" else "list"
            return "any"
        return KIND_NAMES[self.method]

    @property
    def refusals(self) -> list[str]:
        """The parser's refusals beyond the type and range the other columns show."""
        return [m for m in self.messages if not m.startswith("expected ")]

    only_if_given: bool = False  # read only `if r.has(key)`: optional though it has no default

    @property
    def required(self) -> bool:
        if self.method in ("raw", "has"):
            return any(m.startswith("expected a non-empty") for m in self.messages)
        return self.method in ("number", "string") and self.default == "" and not self.only_if_given


@dataclass
class _Scope:
    """What a parser function knows while it is read: its readers' paths and its constant strings."""

    module: str
    readers: dict[str, str]
    strings: dict[str, str]
    conditions: list[str]
    values: dict[str, ast.expr] = field(default_factory=dict)  # local names -> what they were set to


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix and key else prefix or key


class SchemaExtractor:
    """Reads the fields of a file format from the functions that parse it (see the module docstring)."""

    def __init__(self, modules: tuple[str, ...]) -> None:
        self.modules = modules
        self.trees: dict[str, ast.Module] = {}
        self.functions: dict[str, dict[str, ast.FunctionDef]] = {}
        self.imports: dict[str, dict[str, tuple[str, str]]] = {}
        self.namespaces: dict[str, dict[str, object]] = {}
        for name in modules:
            module = importlib.import_module(name)
            tree = ast.parse(inspect.getsource(module))
            self.trees[name] = tree
            self.namespaces[name] = vars(module)
            self.functions[name] = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
            self.imports[name] = {
                alias.asname or alias.name: (node.module, alias.name)
                for node in tree.body
                if isinstance(node, ast.ImportFrom) and node.module in modules
                for alias in node.names
            }
        self.fields: list[SchemaField] = []
        self.messages: dict[str, list[str]] = {}
        self._stack: list[tuple[str, str]] = []

    def extract(self, module: str, function: str) -> list[SchemaField]:
        """The fields that `module.function` reads (given the raw data of a file), in the code's order."""
        self.fields = []
        self.messages = {}
        node = self.functions[module][function]
        params = [a.arg for a in node.args.args]
        strings = {
            name: default.value
            for name, default in zip(reversed(params), reversed(node.args.defaults), strict=False)
            if isinstance(default, ast.Constant) and isinstance(default.value, str)
        }
        self._walk_function(module, node, {}, strings, [])
        fields = _merged(self.fields)
        for f in fields:
            f.messages = self.messages.get(f.path, [])
        return fields

    # --- functions -------------------------------------------------------------------------------

    def _walk_function(
        self,
        module: str,
        node: ast.FunctionDef,
        readers: dict[str, str],
        strings: dict[str, str],
        conditions: list[str],
    ) -> None:
        key = (module, node.name)
        if key in self._stack or len(self._stack) > 12:
            return
        self._stack.append(key)
        scope = _Scope(module, dict(readers), dict(strings), list(conditions))
        for statement in node.body:
            self._visit(statement, scope)
        self._stack.pop()

    def _call_target(self, module: str, func: ast.expr) -> tuple[str, ast.FunctionDef] | None:
        if not isinstance(func, ast.Name):
            return None
        if func.id in self.functions[module]:
            return module, self.functions[module][func.id]
        if func.id in self.imports[module]:
            other, name = self.imports[module][func.id]
            if name in self.functions.get(other, {}):
                return other, self.functions[other][name]
        return None

    def _enter(self, call: ast.Call, scope: _Scope) -> None:
        target = self._call_target(scope.module, call.func)
        if target is None:
            return
        module, node = target
        params = [a.arg for a in node.args.args]
        bound: list[tuple[str, ast.expr]] = list(zip(params, call.args, strict=False))
        bound += [(k.arg, k.value) for k in call.keywords if k.arg is not None]
        readers: dict[str, str] = {}
        strings: dict[str, str] = {}
        for name, arg in bound:
            reader = self._reader(arg, scope)
            if reader is not None:
                readers[name] = reader
                continue
            text = self._path(arg, scope)
            if text is not None:
                strings[name] = text
        for name, default in zip(reversed(params), reversed(node.args.defaults), strict=False):
            if name not in strings and isinstance(default, ast.Constant) and isinstance(default.value, str):
                strings[name] = default.value
        if readers or strings:
            self._walk_function(module, node, readers, strings, scope.conditions)

    # --- expressions -----------------------------------------------------------------------------

    def _path(self, node: ast.expr, scope: _Scope) -> str | None:
        """A path or key the code spells: a string, a bound parameter, an f-string (`faults[{i}]` ->
        `faults[]`), or a reader's `_p(...)` (joined to its path)."""
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            return node.value
        if isinstance(node, ast.Name) and node.id in scope.strings:
            return scope.strings[node.id]
        if isinstance(node, ast.JoinedStr):
            parts = []
            for value in node.values:
                if isinstance(value, ast.Constant):
                    parts.append(str(value.value))
                elif isinstance(value, ast.FormattedValue):
                    inner = self._path(value.value, scope)
                    parts.append(inner or "")
            return "".join(parts)
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "_p"
            and node.args
        ):
            owner = self._reader(node.func.value, scope)
            inner = self._path(node.args[0], scope)
            if owner is not None and inner is not None:
                return _join(owner, inner)
        return None

    def _reader(self, node: ast.expr, scope: _Scope) -> str | None:
        """The path of the reader `node` stands for, or None when it is no reader."""
        if isinstance(node, ast.Name):
            return scope.readers.get(node.id)
        if not isinstance(node, ast.Call):
            return None
        func = node.func
        if isinstance(func, ast.Attribute) and func.attr == "sub" and node.args:
            owner = self._reader(func.value, scope)
            key = self._path(node.args[0], scope)
            if owner is not None and key is not None:
                return _join(owner, key)
            return None
        # A reader built over data: Reader(data, source, path), type(r)(...), a reader class made here.
        if len(node.args) == 3 and self._is_source(node.args[1]):
            return self._path(node.args[2], scope)
        return None

    @staticmethod
    def _is_source(node: ast.expr) -> bool:
        return (isinstance(node, ast.Name) and node.id == "source") or (
            isinstance(node, ast.Attribute) and node.attr == "source"
        )

    def _field(self, call: ast.Call, scope: _Scope) -> None:
        func = call.func
        if not (isinstance(func, ast.Attribute) and func.attr in FIELD_METHODS and call.args):
            return
        owner = self._reader(func.value, scope)
        key = self._path(call.args[0], scope)
        if owner is None or key is None:
            return
        params = dict(zip(FIELD_METHODS[func.attr], call.args[1:], strict=False))
        params.update({k.arg: k.value for k in call.keywords if k.arg is not None})
        namespace = self.namespaces[scope.module]
        rendered = {name: _render(scope.values.get(_name(v), v), namespace) for name, v in params.items()}
        fn = self._stack[-1][1] if self._stack else ""
        path = _join(owner, key)
        self.fields.append(
            SchemaField(
                path=path,
                method=func.attr,
                default=rendered.get("default", ""),
                lo=rendered.get("lo", ""),
                hi=rendered.get("hi", ""),
                choices=rendered.get("choices", ""),
                conditions=[c for c in scope.conditions if not _implied(c, path)],
                only_if_given=f"has({key!r})" in scope.conditions,
                where=f"{scope.module}.{fn}",
            )
        )

    def _loop_keys(self, node: ast.AST, scope: _Scope) -> tuple[str, tuple[str, ...]] | None:
        """A loop over a constant tuple of keys (`for op in CHECK_OPS`): its variable and the keys."""
        if isinstance(node, ast.For):
            target, iterable = node.target, node.iter
        elif isinstance(node, ast.ListComp | ast.GeneratorExp | ast.SetComp) and len(node.generators) == 1:
            target, iterable = node.generators[0].target, node.generators[0].iter
        else:
            return None
        if not isinstance(target, ast.Name) or not _safe(iterable):
            return None
        try:
            value = eval(
                compile(ast.Expression(iterable), "<schema>", "eval"),
                {"__builtins__": builtins, **self.namespaces[scope.module]},
            )
        except Exception:
            return None
        if isinstance(value, tuple) and value and all(isinstance(v, str) for v in value):
            return target.id, value
        return None

    def _message(self, call: ast.Call, scope: _Scope) -> None:
        """A refusal: `r.error(key, message)`, or `SomeError(source, path, message)`."""
        func = call.func
        if isinstance(func, ast.Attribute) and func.attr == "error" and len(call.args) == 2:
            owner = self._reader(func.value, scope)
            key = self._path(call.args[0], scope)
            path = _join(owner, key) if owner is not None and key is not None else None
        elif (
            isinstance(func, ast.Name)
            and (func.id.endswith("Error") or func.id == "error_type")
            and len(call.args) == 3
            and self._is_source(call.args[0])
        ):
            path = self._path(call.args[1], scope)
        else:
            return
        text = _message_text(call.args[-1])
        if path is not None and text and text not in self.messages.setdefault(path, []):
            self.messages[path].append(text)

    # --- statements ------------------------------------------------------------------------------

    def _visit(self, node: ast.AST, scope: _Scope) -> None:
        if isinstance(node, ast.FunctionDef | ast.ClassDef | ast.Lambda):
            return
        if isinstance(node, ast.If | ast.IfExp):
            self._visit(node.test, scope)
            body = node.body if isinstance(node.body, list) else [node.body]
            orelse = node.orelse if isinstance(node.orelse, list) else [node.orelse]
            # A guard kept in a local (`has_xy = r.has("x_m") or r.has("y_m")`) is shown as what it holds.
            test = node.test
            if isinstance(test, ast.Name) and test.id in scope.values:
                test = scope.values[test.id]
            branches = ((body, _condition(test)), (orelse, _condition(_negated(test))))
            for branch, condition in branches:
                scope.conditions.append(condition)
                for child in branch:
                    self._visit(child, scope)
                scope.conditions.pop()
            return
        if isinstance(node, ast.Assign | ast.AnnAssign):
            if node.value is not None:
                self._visit(node.value, scope)
                reader = self._reader(node.value, scope)
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                for target in targets:
                    if isinstance(target, ast.Name):
                        scope.values[target.id] = node.value
                        if reader is not None:
                            scope.readers[target.id] = reader
            return
        if isinstance(node, ast.ListComp | ast.GeneratorExp | ast.SetComp | ast.For):
            keys = self._loop_keys(node, scope)
            if keys is not None:
                name, values = keys
                for value in values:
                    scope.strings[name] = value
                    for child in ast.iter_child_nodes(node):
                        self._visit(child, scope)
                scope.strings.pop(name, None)
                return
        if isinstance(node, ast.Call):
            self._field(node, scope)
            self._message(node, scope)
            self._enter(node, scope)
        for child in ast.iter_child_nodes(node):
            self._visit(child, scope)


def _name(node: ast.expr) -> str:
    return node.id if isinstance(node, ast.Name) else ""


def _negated(test: ast.expr) -> ast.expr:
    """`not test`, spelled the short way where there is one (`kind != 'scripted'`)."""
    flip: dict[type, type] = {ast.Eq: ast.NotEq, ast.NotEq: ast.Eq, ast.In: ast.NotIn, ast.NotIn: ast.In}
    if isinstance(test, ast.Compare) and len(test.ops) == 1 and type(test.ops[0]) in flip:
        return ast.Compare(test.left, [flip[type(test.ops[0])]()], test.comparators)
    if isinstance(test, ast.UnaryOp) and isinstance(test.op, ast.Not):
        return test.operand
    return ast.UnaryOp(ast.Not(), test)


def _condition(test: ast.expr) -> str:
    """A guard as code, with a reader's `r.has('key')` shown as `has('key')` and `r.raw('key')` as
    `key` (the reader's name says nothing to someone writing the file)."""
    text = re.sub(r"\b\w+\.has\(", "has(", ast.unparse(test))
    return re.sub(r"\b\w+\.raw\('(\w+)'\)", r"\1", text)


_GIVEN = re.compile(r"has\('(\w+)'\)(?: and (\w+) is not None)?")


def _implied(condition: str, path: str) -> bool:
    """`has('world')` guards every `world.*` field: a field in a section is only read when it is given."""
    given = _GIVEN.fullmatch(condition)
    segments = path.replace("[]", "").split(".")
    return given is not None and given.group(1) in segments and given.group(2) in (None, given.group(1))


def _message_text(node: ast.expr) -> str:
    """An error message as the code writes it, `{...}` where it fills in a value, without the
    `, got ...` that echoes the bad input."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        text = node.value
    elif isinstance(node, ast.JoinedStr):
        text = "".join(
            str(v.value) if isinstance(v, ast.Constant) else "{" + ast.unparse(v.value) + "}"
            for v in node.values
        )
    else:
        return ""
    return re.sub(r",? got \{.*$", "", text).strip()


def _safe(node: ast.expr) -> bool:
    for sub in ast.walk(node):
        if isinstance(sub, ast.Call) and not (isinstance(sub.func, ast.Name) and sub.func.id in _SAFE_CALLS):
            return False
        if isinstance(sub, ast.Lambda | ast.NamedExpr | ast.Await | ast.Yield):
            return False
    return True


def _render(node: ast.expr, namespace: dict[str, object]) -> str:
    """A default or limit as a reader sees it: evaluated where it is a constant of the module
    (`100.0 * KMH` -> 27.78, `ACTIONS` -> restart | degrade | stop), else the code itself."""
    if isinstance(node, ast.Constant) and node.value is None:
        return ""
    if _safe(node):
        try:
            value = eval(  # a constant expression of our own parser module
                compile(ast.Expression(node), "<schema>", "eval"), {"__builtins__": builtins, **namespace}
            )
        except Exception:
            value = None
        else:
            return _format(value)
    return f"`{ast.unparse(node)}`"


def _format(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return str(int(value)) if value.is_integer() and abs(value) < 1e16 else f"{value:.6g}"
    if isinstance(value, tuple | list) and all(isinstance(v, str) for v in value):
        return " \\| ".join(f"`{v}`" for v in value) if value else "[]"
    if isinstance(value, dict) and not value:
        return "{}"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)


def _merged(fields: list[SchemaField]) -> list[SchemaField]:
    """One row per path and method: a field read under different conditions is read under any of
    them, and one read unconditionally anywhere is read always."""
    out: dict[tuple[str, str], SchemaField] = {}
    for f in fields:
        seen = out.get((f.path, f.method))
        if seen is None:
            out[(f.path, f.method)] = f
            continue
        if not f.conditions or not seen.conditions:
            seen.conditions = []
        elif f.conditions != seen.conditions:
            mine = " and ".join(seen.conditions)
            theirs = " and ".join(f.conditions)
            seen.conditions = [f"({mine}) or ({theirs})"] if mine != theirs else seen.conditions
    # A `raw` read of a key that is also read as a typed field, or of a section whose fields are
    # rows of their own (`world`), adds nothing; a list's row (`faults`) stays beside its items'.
    untyped = ("raw", "has")
    typed = {path for (path, method) in out if method not in untyped}
    sections = {path.rpartition(".")[0] for (path, _) in out}
    kept: dict[str, SchemaField] = {}
    for (path, method), f in out.items():
        if method in untyped and (path in typed or path in sections or path in kept):
            continue
        f.has_items = any(other.startswith(f"{path}[]") for (other, _) in out)
        kept.setdefault(path, f) if method in untyped else kept.__setitem__(path, f)
    return list(kept.values())


def iter_sections(fields: list[SchemaField]) -> Iterator[tuple[str, list[SchemaField]]]:
    """The fields grouped by the mapping they stand in (`""` for the top level), in the code's order."""
    groups: dict[str, list[SchemaField]] = {}
    for f in fields:
        parent, _, _ = f.path.rpartition(".")
        groups.setdefault(parent, []).append(f)

    def first(section: str) -> int:
        # A section stands where its first field or its subsections' first field does: `world`
        # before `world.road`, though the parser reads `world.trace_hz` last.
        inside = (section + ".", section + "[]") if section else ("",)
        return min(i for i, f in enumerate(fields) if f.path.startswith(inside))

    yield from sorted(groups.items(), key=lambda item: (first(item[0]), item[0].count(".")))
