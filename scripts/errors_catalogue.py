#!/usr/bin/env python3
"""Print the catalogue of every error message of msleak (the last part of docs/errors.md).

Reads the source with :mod:`ast` (of msleak only the command line's rewrite of parameter
names, :func:`msleak.cli._flags.rewrite`, is imported):
every ``raise`` of one of msleak's error classes (``MsleakError`` and its subclasses:
``InputError``, ``ConfigurationError``, ``BeamUnavailable``, ``DegridRefused``, ...), every
such error a function builds and returns (``return MsleakError(...)``), and the
``click.BadParameter``/``click.UsageError`` of the command line. For each it renders

* the message template: literal text, ``{expr}`` for an f-string field, ``[...]`` for a
  part added only sometimes, ``{a|b}`` for a choice inside the message; a message
  chosen between whole alternatives gives one row per alternative; a message held in a
  variable is looked up (assignments in its function or module, the loop it is raised in,
  the function that returns it), and what cannot be resolved is written ``...``. An error
  class whose ``__init__`` builds the message (``BeamUnavailable``, ``DegridRefused``) is
  rendered through that ``__init__``;
* the message as the command line shows it: each parameter the error names (``param=``,
  and settings quoted as `` `name=value` ``) rewritten as msleak/cli/_flags.py:as_flags
  does, with the flag in its ``ALIASES``, else the option of the section's command that
  sets that parameter under another name (``--plot-channel`` for ``channel``), else
  ``--name-with-dashes``;
* where: ``package/module.py:function`` (``Class.method`` for methods);
* the test files (tests/**/test_*.py, basenames) holding a string literal of at least
  ``MIN_FRAGMENT`` characters with a space in it that is part of the message's literal
  text, or that contains a literal part of the message of that length.

Rows are grouped by command (``ROUTES`` maps modules, or functions, to ``SECTIONS``);
identical messages of one section share a row.

Usage: python scripts/errors_catalogue.py [--counts]   (--counts: raise sites per section
on stderr)
"""

from __future__ import annotations

import ast
import fnmatch
import itertools
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

from msleak.cli._flags import ALIASES, rewrite

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "msleak"
TESTS = ROOT / "tests"
MIN_FRAGMENT = 12
#: error classes the command line turns into "msleak: error: ..." (their subclasses are
#: found in the source)
BASE_ERRORS = {"MsleakError", "InputError", "ConfigurationError", "BeamUnavailable"}
CLICK_ERRORS = {"BadParameter", "UsageError"}
#: rows of a class derived from InputError carry no class name; the others do
INPUT_ERROR = "InputError"

#: the sections, in page order
SECTIONS = [
    "Every command reading a Measurement Set (predict, grid, beam)",
    "simulate",
    "sky",
    "sky models (predict --sky, sky --crop FILE.skymodel)",
    "beam",
    "predict",
    "noise",
    "grid",
    "predict and grid: parallel execution and several MSs",
    "transform",
    "ps",
    "leakage",
    "paper and forecast",
    "product files (grid, transform, ps, leakage, beam --product)",
    "option parsing shared by several commands",
]
MS, SIMULATE, SKY, SKYMODEL, BEAM, PREDICT, NOISE, GRID, PARALLEL, TRANSFORM, PS, LEAKAGE, \
    PAPER, PRODUCTS, OPTIONS = SECTIONS
#: ("module.py:function" pattern relative to msleak/, section): the first match decides;
#: within a section rows follow this order, then file and line
ROUTES: list[tuple[str, str]] = [
    ("conventions.py:*", MS), ("io/ms.py:resolve_*", GRID), ("io/ms.py:*", MS),
    ("io/casacore_data.py:*", MS), ("io/measures.py:*", MS),
    ("cli/simulate.py:*", SIMULATE), ("verbs/simulate.py:*", SIMULATE),
    ("telescope/noise.py:*", NOISE), ("telescope/*", SIMULATE),
    ("io/ms_create.py:*", SIMULATE),
    ("io/phased_array.py:read_*", BEAM), ("io/phased_array.py:*", SIMULATE),
    ("cli/sky.py:*", SKY), ("verbs/sky.py:*", SKY), ("adapters/sky_fits.py:*", SKY),
    ("io/fits.py:*", SKY), ("plot/sky.py:*", SKY), ("sky/*", SKY),
    ("adapters/skymodel.py:*", SKYMODEL),
    ("cli/predict.py:*", PREDICT), ("verbs/predict*.py:*", PREDICT), ("predict/*", PREDICT),
    ("io/columns.py:*", PREDICT), ("parallel/runner.py:parse_memory", PREDICT),
    ("adapters/ionosphere.py:*", PREDICT), ("beam/ionosphere.py:*", PREDICT),
    ("adapters/spinifex_rm.py:*", PREDICT),
    ("cli/beam.py:*", BEAM), ("verbs/beam_maps.py:*", BEAM), ("_everybeam.py:*", BEAM),
    ("adapters/beams.py:*", BEAM), ("adapters/everybeam.py:*", BEAM), ("beam/*", BEAM),
    ("io/lofar.py:*", BEAM), ("io/mwa.py:*", BEAM), ("io/uvbeam.py:*", BEAM),
    ("plot/beam.py:*", BEAM),
    ("cli/noise.py:*", NOISE), ("verbs/noise.py:*", NOISE),
    ("cli/grid.py:*", GRID), ("verbs/grid.py:*", GRID), ("verbs/grid_tasks.py:*", GRID),
    ("verbs/images.py:*", GRID), ("io/images.py:*", GRID), ("ps/chunks.py:*", GRID),
    ("ps/gridding.py:*", GRID), ("ps/image.py:*", GRID), ("ps/beam_area.py:*", GRID),
    ("ps/uvcube.py:*", GRID),
    ("parallel/*", PARALLEL),
    ("cli/transform.py:*", TRANSFORM), ("verbs/transform.py:*", TRANSFORM),
    ("ps/delay.py:*", TRANSFORM),
    ("cli/ps.py:*", PS), ("verbs/power.py:*", PS), ("ps/*", PS), ("plot/ps.py:*", PS),
    ("cli/leakage.py:*", LEAKAGE), ("verbs/leakage*.py:*", LEAKAGE), ("leakage/*", LEAKAGE),
    ("plot/leakage.py:*", LEAKAGE),
    ("cli/paper.py:*", PAPER), ("cli/forecast.py:*", PAPER), ("study/*", PAPER),
    ("plot/forecast.py:*", PAPER),
    ("io/products.py:*", PRODUCTS),
    ("cli/*", OPTIONS),
]

INTRO = f"""\
## Catalogue of every error message

Generated from the source by `scripts/errors_catalogue.py` (run it to regenerate this
part): every `raise` of msleak's errors (`InputError` and its subclasses without a mark,
the others with their class in brackets) and of `click.BadParameter`/`click.UsageError`,
with the message as a template (`{{...}}` is filled in at run time, `[...]` is added only
sometimes, `{{a|b}}` is one of these, `...` is text the script could not resolve) and the
function raising it. Messages are shown as the command line prints them: the Python API
names the parameters (`epsilon`, `` `beam='dipole'` ``) where the command names flags
(`--epsilon`, `` `--beam dipole` ``). The last column names test files containing a
string literal of at least {MIN_FRAGMENT} characters (with a space) that is part of the
message, or that contains a literal part of it of that length; tests matching on shorter
fragments (`"read-only"`, `"flagged"`) are not detected by this rule, so "—" means "not
matched by that rule", not necessarily untested. API-level checks (arguments only a
Python caller can get wrong) are included.
"""


# -- templates -------------------------------------------------------------------------
# A template is a tuple of segments: ("lit", text) or ("ph", expression). A rendering is a
# list of templates (the alternatives: one row each).

Seg = tuple[str, str]
Tpl = tuple[Seg, ...]
EMPTY: Tpl = ()
UNKNOWN: Tpl = (("lit", "..."),)


def lit(text: str) -> Tpl:
    return (("lit", text),) if text else EMPTY


def ph(expr: str) -> Tpl:
    return (("ph", expr),)


def concat(*parts: Tpl) -> Tpl:
    out: list[Seg] = []
    for part in parts:
        for kind, text in part:
            if out and kind == "lit" and out[-1][0] == "lit":
                out[-1] = ("lit", out[-1][1] + text)
            elif text or kind == "ph":
                out.append((kind, text))
    return tuple(out)


def product(*alternatives: list[Tpl]) -> list[Tpl]:
    return [concat(*combo) for combo in itertools.product(*alternatives)]


def as_text(tpl: Tpl) -> str:
    return "".join(text if kind == "lit" else "{" + text + "}" for kind, text in tpl)


def literal_parts(tpl: Tpl) -> list[str]:
    return [text for kind, text in tpl if kind == "lit"]


# -- the source ------------------------------------------------------------------------

@dataclass
class Module:
    rel: str                      # path relative to msleak/
    tree: ast.Module
    parents: dict[int, ast.AST] = field(default_factory=dict)
    functions: dict[str, ast.FunctionDef] = field(default_factory=dict)  # top level
    imports: dict[str, str] = field(default_factory=dict)   # name -> module rel path

    def parent(self, node: ast.AST) -> ast.AST | None:
        return self.parents.get(id(node))


def load_modules() -> dict[str, Module]:
    modules = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        tree = ast.parse(path.read_text(), str(path))
        mod = Module(rel, tree)
        for node in ast.walk(tree):
            for child in ast.iter_child_nodes(node):
                mod.parents[id(child)] = node
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                mod.functions[node.name] = node
        package = rel.rsplit("/", 1)[0].split("/") if "/" in rel else []
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package[:len(package) - node.level + 1]
                    parts = base + (node.module.split(".") if node.module else [])
                elif (node.module or "").startswith("msleak"):
                    parts = node.module.split(".")[1:]
                else:
                    continue
                for alias in node.names:
                    mod.imports[alias.asname or alias.name] = "/".join(parts) + ".py"
        modules[rel] = mod
    return modules


def call_name(node: ast.AST) -> str:
    func = node.func if isinstance(node, ast.Call) else node
    if isinstance(func, ast.Attribute):
        return func.attr
    return func.id if isinstance(func, ast.Name) else ""


@dataclass
class Wrapper:
    """An error class whose ``__init__`` builds the message: ``super().__init__(msg, ...)``."""
    args: ast.arguments
    message: ast.AST
    param: ast.AST | None


def error_classes(modules: dict[str, Module]) -> tuple[dict[str, str], dict[str, Wrapper]]:
    """class name -> its base family (InputError or the class itself), and wrappers."""
    bases: dict[str, str] = {}
    defs: dict[str, ast.ClassDef] = {}
    for mod in modules.values():
        for node in ast.walk(mod.tree):
            if isinstance(node, ast.ClassDef):
                defs[node.name] = node
    known = set(BASE_ERRORS)
    changed = True
    while changed:
        changed = False
        for name, node in defs.items():
            if name not in known and any(call_name(b) in known for b in node.bases):
                known.add(name)
                changed = True
    for name in known:
        chain, current = [name], name
        while current in defs and current != "MsleakError":
            parent = next((call_name(b) for b in defs[current].bases
                           if call_name(b) in known), None)
            if parent is None:
                break
            chain.append(parent)
            current = parent
        bases[name] = INPUT_ERROR if INPUT_ERROR in chain else name
    wrappers = {}
    for name in known:
        node = defs.get(name)
        init = next((n for n in node.body if isinstance(n, ast.FunctionDef)
                     and n.name == "__init__"), None) if node else None
        if init is None:
            continue
        for call in ast.walk(init):
            if (isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)
                    and call.func.attr == "__init__" and isinstance(call.func.value, ast.Call)
                    and call_name(call.func.value) == "super" and call.args):
                param = next((k.value for k in call.keywords if k.arg == "param"), None)
                wrappers[name] = Wrapper(init.args, call.args[0], param)
    return bases, wrappers


# -- rendering ---------------------------------------------------------------------------

def is_stringy(node: ast.AST) -> bool:
    if isinstance(node, ast.Constant):
        return isinstance(node.value, str)
    if isinstance(node, ast.JoinedStr):
        return True
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return is_stringy(node.left) or is_stringy(node.right)
    if isinstance(node, ast.IfExp):
        return is_stringy(node.body) or is_stringy(node.orelse)
    return False


@dataclass
class Context:
    mod: Module
    modules: dict[str, Module]
    scope: ast.AST                         # the function (or module) the code is in
    env: dict[str, list[Tpl]] = field(default_factory=dict)
    flags: dict[str, Tpl] = field(default_factory=dict)   # variable -> how a field shows
    depth: int = 0


def assignments(scope: ast.AST, name: str) -> tuple[list[ast.AST], list[ast.AST]]:
    """The values assigned to ``name`` in ``scope`` (not in nested functions): plain
    assignments and ``+=``."""
    plain, added = [], []

    def walk(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef,
                                  ast.Lambda)):
                continue
            if isinstance(child, ast.Assign) and len(child.targets) == 1 \
                    and isinstance(child.targets[0], ast.Name) and child.targets[0].id == name:
                plain.append(child.value)
            elif isinstance(child, ast.AnnAssign) and isinstance(child.target, ast.Name) \
                    and child.target.id == name and child.value is not None:
                plain.append(child.value)
            elif isinstance(child, ast.AugAssign) and isinstance(child.target, ast.Name) \
                    and child.target.id == name and isinstance(child.op, ast.Add):
                added.append(child.value)
            walk(child)
    walk(scope)
    return plain, added


def truth(alternatives: list[Tpl]) -> bool | None:
    if all(t == EMPTY for t in alternatives):
        return False
    if all(any(k == "lit" and x for k, x in t) for t in alternatives):
        return True
    return None


def render(node: ast.AST, ctx: Context, top: bool = False) -> list[Tpl]:
    """The alternatives of a string expression; ``top``: a choice between whole
    messages gives alternatives, elsewhere it is written ``{a|b}``."""
    if ctx.depth > 12:
        return [UNKNOWN]
    if isinstance(node, ast.Constant):
        return [lit(node.value if isinstance(node.value, str) else repr(node.value))]
    if isinstance(node, ast.JoinedStr):
        parts = []
        for value in node.values:
            if isinstance(value, ast.Constant):
                parts.append([lit(value.value)])
            else:
                parts.append(render_field(value.value, ctx))
        return product(*parts)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add) and is_stringy(node):
        return product(render(node.left, ctx, top), render(node.right, ctx, top))
    if isinstance(node, ast.IfExp):
        leaves = [render_branches(leaf, ctx) for leaf in branches(node, ctx)]
        alternatives = [t for leaf in leaves for t in leaf]
        if EMPTY in alternatives and len(set(alternatives)) > 1:
            rest = [t for t in alternatives if t != EMPTY]
            return [concat(lit("["), t, lit("]")) for t in choice(rest, top=False)]
        return choice(alternatives, top)
    if isinstance(node, ast.Name):
        return render_name(node.id, ctx, top)
    if isinstance(node, ast.Call):
        return render_call(node, ctx, top)
    return [ph(ast.unparse(node))]


def branches(node: ast.AST, ctx: Context) -> list[ast.AST]:
    """The expressions a chain of conditional expressions may give (the ones a known
    condition rules out left out)."""
    if not isinstance(node, ast.IfExp):
        return [node]
    test = condition(node.test, ctx)
    if test is not None:
        return branches(node.body if test else node.orelse, ctx)
    return branches(node.body, ctx) + branches(node.orelse, ctx)


def render_branches(node: ast.AST, ctx: Context) -> list[Tpl]:
    """A branch of a conditional expression: its text, or ``{expr}``."""
    if isinstance(node, ast.Call):
        return render_call(node, ctx, top=False)
    if isinstance(node, ast.Name) or is_stringy(node):
        return render(node, ctx)
    return [ph(ast.unparse(node))]


def condition(test: ast.AST, ctx: Context) -> bool | None:
    if isinstance(test, ast.Name) and test.id in ctx.env:
        return truth(ctx.env[test.id])
    if isinstance(test, ast.UnaryOp) and isinstance(test.op, ast.Not):
        inner = condition(test.operand, ctx)
        return None if inner is None else not inner
    return None


def render_field(node: ast.AST, ctx: Context) -> list[Tpl]:
    """An f-string field: a string expression, a variable or a call of msleak holding
    text is rendered; anything else is ``{expr}``."""
    if isinstance(node, ast.Name) or is_stringy(node):
        return render(node, ctx)
    if isinstance(node, ast.Call):
        return render_call(node, ctx, top=False)
    return [ph(ast.unparse(node))]


def choice(alternatives: list[Tpl], top: bool) -> list[Tpl]:
    """Alternatives: separate rows at the top of a message, else ``{a|b}``."""
    alternatives = list(dict.fromkeys(alternatives))
    if top or len(alternatives) == 1:
        return alternatives
    return [concat(lit("{"), *[concat(lit("|") if i else EMPTY, t)
                               for i, t in enumerate(alternatives)], lit("}"))]


def unresolved(alternatives: list[Tpl]) -> bool:
    """Whether some alternative says nothing of its own: empty, unknown, or one field and
    punctuation (a variable is then shown by its name)."""
    def empty(t: Tpl) -> bool:
        words = any(k == "lit" and re.search(r"\w", x) for k, x in t)
        return t == UNKNOWN or not words and sum(k == "ph" for k, _ in t) < 2
    return not alternatives or any(empty(t) for t in alternatives)


def render_name(name: str, ctx: Context, top: bool) -> list[Tpl]:
    """A variable: its binding (loop, wrapper), else the text assigned to it in its
    function, its module or the module it is imported from."""
    if name in ctx.flags:
        return [ctx.flags[name]]
    if name in ctx.env:
        return ctx.env[name]
    fallback = [UNKNOWN] if top else [ph(name)]
    places = [(ctx.mod, ctx.scope)]
    if ctx.scope is not ctx.mod.tree:
        args = ctx.scope.args if isinstance(ctx.scope, (ast.FunctionDef,
                                                        ast.AsyncFunctionDef)) else None
        if args and name in {a.arg for a in args.args + args.kwonlyargs + args.posonlyargs}:
            places = [(ctx.mod, ctx.scope)]           # a parameter: only its function
        else:
            places.append((ctx.mod, ctx.mod.tree))
    other = ctx.mod.imports.get(name)
    if other in ctx.modules:
        places.append((ctx.modules[other], ctx.modules[other].tree))
    for mod, scope in places:
        plain, added = assignments(scope, name)
        if not plain:
            continue
        sub = Context(mod, ctx.modules, scope, ctx.env, ctx.flags, ctx.depth + 1)
        base = []
        for value in plain:
            if isinstance(value, ast.Call):
                rendered = render_call(value, sub, top)
            elif is_stringy(value) or isinstance(value, ast.Name):
                rendered = render(value, sub, top)
            else:
                return fallback
            if unresolved(rendered):
                return fallback
            base += rendered
        base = choice(base, top)
        for value in added:
            extra = render(value, sub)
            base = [concat(t, lit("["), e, lit("]")) for t in base for e in extra]
        return list(dict.fromkeys(base))
    return fallback


def find_function(name: str, mod: Module, modules: dict[str, Module]):
    if name in mod.functions:
        return mod, mod.functions[name]
    other = mod.imports.get(name)
    if other in modules and name in modules[other].functions:
        return modules[other], modules[other].functions[name]
    return None


def render_call(node: ast.Call, ctx: Context, top: bool) -> list[Tpl]:
    """Text made by a function of msleak (the strings it returns), or looked up in a
    dictionary of strings (``TABLE.get(key, default)``: any of its values)."""
    func = node.func
    if isinstance(func, ast.Attribute) and func.attr == "get" and isinstance(func.value,
                                                                            ast.Name):
        table = None
        for scope in (ctx.scope, ctx.mod.tree):
            plain, _ = assignments(scope, func.value.id)
            if len(plain) == 1 and isinstance(plain[0], ast.Dict):
                table = plain[0]
                break
        if table is not None:
            values = list(table.values) + node.args[1:2]
            rendered = [t for v in values for t in render(v, ctx)]
            if all(is_stringy(v) for v in values) and not unresolved(rendered):
                return choice(rendered, top)
    if isinstance(func, ast.Name) and ctx.depth < 8:
        target = find_function(func.id, ctx.mod, ctx.modules)
        if target is not None:
            mod, function = target
            sub = Context(mod, ctx.modules, function, {}, {}, ctx.depth + 1)
            out = []
            for ret in ast.walk(function):
                if isinstance(ret, ast.Return) and ret.value is not None:
                    if is_stringy(ret.value) or isinstance(ret.value, ast.Name):
                        out += render(ret.value, sub, top)
                    elif isinstance(ret.value, ast.Call):
                        out += render_call(ret.value, sub, top)
                    else:
                        out = []
                        break
            if out and not unresolved(out):
                return choice(out, top)
    return [ph(ast.unparse(node))]


# -- parameters and the command line's flags ---------------------------------------------

SETTING = re.compile(r"`([a-z_][a-z0-9_]*)=")
#: section -> the commands whose errors it lists (for options named unlike their flag)
SECTION_COMMANDS = {SIMULATE: ("simulate",), SKY: ("sky",), SKYMODEL: ("sky", "predict"),
                    BEAM: ("beam", "predict"), PREDICT: ("predict",), NOISE: ("noise",),
                    GRID: ("grid",), TRANSFORM: ("transform",), PS: ("ps",),
                    LEAKAGE: ("leakage",), PAPER: ("paper", "forecast")}


def command_options(modules: dict[str, Module]) -> dict[str, dict[str, str]]:
    """command -> {parameter: flag} for the options of msleak/cli/<command>.py whose
    parameter is not named after the flag (``click.option("--plot-channel", "channel")``),
    as :func:`msleak.cli._flags.flag_for` reads them from the command."""
    commands = {}
    init = modules["cli/__init__.py"].tree
    for node in ast.walk(init):
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "COMMANDS"
                                                for t in node.targets):
            commands = ast.literal_eval(node.value)
    out: dict[str, dict[str, str]] = {}
    for command, target in commands.items():
        module, function = target.split(":")
        mod = modules.get(f"cli/{module}.py")
        if mod is None or function not in mod.functions:
            continue
        named: dict[str, str] = {}
        _named_options(mod.tree, mod, named)
        # decorators adding options, from other modules (``@physics_options``)
        for deco in mod.functions[function].decorator_list:
            target_def = find_function(call_name(deco), mod, modules)
            if target_def is not None and target_def[0] is not mod:
                _named_options(target_def[1], target_def[0], named)
        out[command] = named
    return out


def _named_options(tree: ast.AST, mod: Module, named: dict[str, str]) -> None:
    """Add the options of ``tree`` given a parameter name of their own: literal
    ``click.option("--flag", "name")`` calls, and tables ``{"name": ("--flag", ...)}``
    (of ``mod``) that ``tree`` uses."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and call_name(node) == "option":
            names = [a.value for a in node.args
                     if isinstance(a, ast.Constant) and isinstance(a.value, str)]
            flags = [n for n in names if n.startswith("-")]
            ident = [n for n in names if not n.startswith("-")]
            longs = [f for f in flags if f.startswith("--")] or flags
            if ident and longs:
                named[ident[0]] = longs[0]
        elif isinstance(node, ast.Name) and tree is not mod.tree:
            plain, _ = assignments(mod.tree, node.id)
            if len(plain) == 1 and isinstance(plain[0], ast.Dict):
                for key, value in zip(plain[0].keys, plain[0].values):
                    if isinstance(key, ast.Constant) and isinstance(value, ast.Tuple) \
                            and value.elts and isinstance(value.elts[0], ast.Constant) \
                            and str(value.elts[0].value).startswith("--"):
                        named[key.value] = value.elts[0].value


COMMAND_OPTIONS: dict[str, dict[str, str]] = {}


def flag_for(param: str, section: str = "") -> str:
    """The flag of ``param`` in the commands of ``section``: ALIASES, an option of theirs
    named ``param``, else ``--param-with-dashes``."""
    if param in ALIASES:
        return ALIASES[param]
    own = {COMMAND_OPTIONS.get(c, {}).get(param) for c in SECTION_COMMANDS.get(section, ())}
    own.discard(None)
    if len(own) == 1:
        return own.pop()
    return "--" + param.replace("_", "-")


def as_flags(text: str, params: list[str], section: str = "") -> str:
    """msleak/cli/_flags.py:rewrite on a message (fields replaced by private characters),
    with the flags of the section's commands."""
    return rewrite(text, params, lambda p: flag_for(p, section))


def cli_template(tpl: Tpl, params: list[str], section: str) -> Tpl:
    """The template as the command line shows it."""
    fields = [text for kind, text in tpl if kind == "ph"]
    masked = "".join(text if kind == "lit" else chr(0xE000 + fields.index(text))
                     for kind, text in tpl)
    settings = SETTING.findall("".join(literal_parts(tpl)))
    shown = as_flags(masked, list(dict.fromkeys(params + settings)), section)
    out: list[Tpl] = []
    for piece in re.split(r"([\ue000-\ue8ff])", shown):
        if len(piece) == 1 and 0xE000 <= ord(piece) <= 0xE8FF:
            out.append(ph(fields[ord(piece) - 0xE000]))
        else:
            out.append(lit(piece))
    return concat(*out)


def loop_values(node: ast.AST, mod: Module,
                scope: ast.AST) -> list[dict[str, ast.AST]] | None:
    """Per iteration of the ``for`` loops around ``node`` over literal sequences: the
    values of their target names."""
    combos: list[dict[str, ast.AST]] = [{}]
    found = False
    current = mod.parent(node)
    while current is not None and current is not scope:
        if isinstance(current, ast.For):
            rows = literal_rows(current.iter, scope)
            names = current.target
            if rows is not None:
                found = True
                per = []
                for row in rows:
                    binding = {}
                    if isinstance(names, ast.Name):
                        binding[names.id] = row
                    elif isinstance(names, ast.Tuple) and isinstance(
                            row, (ast.Tuple, ast.List)) and len(row.elts) == len(names.elts):
                        for t, v in zip(names.elts, row.elts):
                            if isinstance(t, ast.Name):
                                binding[t.id] = v
                    per.append(binding)
                combos = [{**a, **b} for a in combos for b in per]
        current = mod.parent(current)
    return combos if found else None


def literal_rows(iterable: ast.AST, scope: ast.AST) -> list[ast.AST] | None:
    if isinstance(iterable, ast.Name):
        plain, _ = assignments(scope, iterable.id)
        if len(plain) == 1:
            return literal_rows(plain[0], scope)
        return None
    if isinstance(iterable, (ast.Tuple, ast.List)):
        return list(iterable.elts)
    if isinstance(iterable, ast.Call) and isinstance(iterable.func, ast.Attribute) \
            and iterable.func.attr in ("items", "keys"):
        obj = iterable.func.value
        if isinstance(obj, ast.Name):
            plain, _ = assignments(scope, obj.id)
            obj = plain[0] if len(plain) == 1 else None
        if isinstance(obj, ast.Dict) and all(k is not None for k in obj.keys):
            if iterable.func.attr == "keys":
                return list(obj.keys)
            return [ast.Tuple(elts=[k, v], ctx=ast.Load())
                    for k, v in zip(obj.keys, obj.values)]
    return None


def param_names(node: ast.AST | None,
                values: dict[str, list[str]]) -> tuple[list[str], list[str]]:
    """(parameter names, names of variables whose value is a parameter) of ``param=``."""
    if node is None:
        return [], []
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value], []
    if isinstance(node, ast.Name):
        if node.id in values:
            return values[node.id], [node.id]
        return [], [node.id]
    if isinstance(node, (ast.Tuple, ast.List)):
        names, variables = [], []
        for elt in node.elts:
            n, v = param_names(elt.value if isinstance(elt, ast.Starred) else elt, values)
            names += n
            variables += v
        return names, variables
    return [], []


# -- raise sites -----------------------------------------------------------------------

@dataclass
class Site:
    rel: str
    where: str                     # function qualname
    line: int
    cls: str
    family: str
    messages: list[Tpl]            # as the command line shows them
    python: list[Tpl]              # as the library words them
    named: list[tuple[Tpl, tuple[str, ...]]] = field(default_factory=list)  # with params


def qualname(mod: Module, node: ast.AST) -> tuple[str, ast.AST]:
    names, scope = [], None
    current = mod.parent(node)
    while current is not None:
        if isinstance(current, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.append(current.name)
            if scope is None and not isinstance(current, ast.ClassDef):
                scope = current
        current = mod.parent(current)
    return ".".join(reversed(names)) or "<module>", scope or mod.tree


def bind(wrapper: Wrapper, call: ast.Call) -> dict[str, ast.AST]:
    args = [a.arg for a in wrapper.args.args[1:]]
    defaults = dict(zip(args[len(args) - len(wrapper.args.defaults):], wrapper.args.defaults))
    defaults.update({a.arg: d for a, d in zip(wrapper.args.kwonlyargs,
                                              wrapper.args.kw_defaults) if d is not None})
    bound = dict(defaults)
    bound.update(zip(args, call.args))
    bound.update({k.arg: k.value for k in call.keywords if k.arg})
    return bound


def site_of(mod: Module, call: ast.Call, cls: str, ctx_base: dict) -> Site:
    modules, bases, wrappers = ctx_base["modules"], ctx_base["bases"], ctx_base["wrappers"]
    where, scope = qualname(mod, call)
    section = route(mod.rel, where)[0]
    is_click = cls in CLICK_ERRORS
    param_node = None if is_click else next((k.value for k in call.keywords
                                             if k.arg == "param"), None)
    message_node = call.args[0] if call.args else next(
        (k.value for k in call.keywords if k.arg in ("message", "reason")), ast.Constant(""))
    iterations = loop_values(call, mod, scope) or [{}]
    # a loop over literal rows: one row per iteration when the message itself comes from
    # the loop, else the loop variables are shown as {a|b}
    loop_message = isinstance(message_node, ast.Name) and any(
        message_node.id in it for it in iterations)
    if not loop_message and len(iterations) > 1:
        merged: dict[str, list[ast.AST]] = {}
        for it in iterations:
            for k, v in it.items():
                merged.setdefault(k, []).append(v)
        iterations = [{"__merged__": merged}]
    python_all, cli_all, named = [], [], []
    for it in iterations:
        ctx = Context(mod, modules, scope)
        values: dict[str, list[str]] = {}
        merged = it.get("__merged__")
        bindings = merged if merged is not None else {k: [v] for k, v in it.items()}
        for name, nodes in bindings.items():
            if all(isinstance(n, ast.Constant) and isinstance(n.value, str) for n in nodes):
                values[name] = list(dict.fromkeys(n.value for n in nodes))
                ctx.env[name] = choice([lit(v) for v in values[name]], top=False)
            elif merged is None and len(nodes) == 1:
                ctx.env[name] = render(nodes[0], ctx)
        params_node, bound = param_node, {}
        if cls in wrappers:
            wrapper = wrappers[cls]
            bound = bind(wrapper, call)
            if isinstance(wrapper.param, ast.Name) and wrapper.param.id in bound:
                params_node = bound[wrapper.param.id]
            elif wrapper.param is not None:
                params_node = wrapper.param
        names, variables = param_names(params_node, values)
        for variable in variables:
            if variable not in values:
                ctx.flags[variable] = concat(lit("--"), ph(variable))
        if cls in wrappers:
            init = Context(mod, modules, wrappers[cls].message, dict(ctx.env))
            for name, value in bound.items():
                init.env[name] = render(value, ctx)
            python = render(wrappers[cls].message, init, top=True)
        else:
            python = render(message_node, ctx, top=True)
        for tpl in python:
            python_all.append(tpl)
            cli_all.append(tpl if is_click else cli_template(tpl, names, section))
            named.append((tpl, tuple(names)))
    family = "click" if is_click else bases[cls]
    return Site(mod.rel, where, call.lineno, cls, family,
                list(dict.fromkeys(cli_all)), list(dict.fromkeys(python_all)), named)


def find_sites(modules: dict[str, Module]) -> list[Site]:
    bases, wrappers = error_classes(modules)
    base = {"modules": modules, "bases": bases, "wrappers": wrappers}
    sites = []
    for mod in modules.values():
        if mod.rel == "errors.py":
            continue            # the classes themselves
        for node in ast.walk(mod.tree):
            if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call):
                call = node.exc
            elif isinstance(node, ast.Return) and isinstance(node.value, ast.Call):
                call = node.value
            else:
                continue
            cls = call_name(call)
            if cls in bases or cls in CLICK_ERRORS:
                sites.append(site_of(mod, call, cls, base))
    return sorted(sites, key=lambda s: (s.rel, s.line))


# -- tests -------------------------------------------------------------------------------

GRAM = 8            # characters a test literal must share with a message to be compared
VALUE = r"[^\n]{1,80}?"   # what a field of the message may stand for in a test literal


def test_literals() -> dict[str, set[str]]:
    """test file basename -> its string literals of at least MIN_FRAGMENT characters with
    a space (docstrings left out; regular-expression escapes undone)."""
    out: dict[str, set[str]] = {}
    for path in sorted(TESTS.rglob("test_*.py")):
        tree = ast.parse(path.read_text(), str(path))
        docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                      if isinstance(n, (ast.Module, ast.FunctionDef, ast.ClassDef,
                                        ast.AsyncFunctionDef))
                      and n.body and isinstance(n.body[0], ast.Expr)
                      and isinstance(n.body[0].value, ast.Constant)}
        found = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                    and id(node) not in docstrings:
                for text in (node.value, re.sub(r"\\(.)", r"\1", node.value)):
                    if len(text) >= MIN_FRAGMENT and " " in text:
                        found.add(text)
        out.setdefault(path.stem, set()).update(found)
    return out


class TestIndex:
    """The test literals, indexed by their GRAM-character pieces."""

    def __init__(self, literals: dict[str, set[str]]):
        self.texts = sorted({t for texts in literals.values() for t in texts})
        self.files = {t: set() for t in self.texts}
        for test, texts in literals.items():
            for t in texts:
                self.files[t].add(test)
        self.grams: dict[str, set[int]] = {}
        for i, t in enumerate(self.texts):
            for k in range(len(t) - GRAM + 1):
                self.grams.setdefault(t[k:k + GRAM], set()).add(i)

    def candidates(self, tpl: Tpl) -> set[int]:
        out: set[int] = set()
        for part in literal_parts(tpl):
            for k in range(len(part) - GRAM + 1):
                out |= self.grams.get(part[k:k + GRAM], set())
        return out


def fits(text: str, tpl: Tpl) -> bool:
    """Whether ``text`` is part of a message of template ``tpl`` with at least
    MIN_FRAGMENT characters of the template's literal text in it (its fields standing
    for up to 80 characters of one line; one word where the text starts or ends inside
    a field)."""
    segments = list(tpl)
    for i, (kind, part) in enumerate(segments):
        if kind != "lit":
            continue
        if text in part or distinctive(part) and part in text:
            return True           # the test's text in a literal part, or one in the text
        starts = [k for k in range(1, min(len(part), len(text)) + 1)
                  if part.endswith(text[:k])]
        # or the text starts inside the field before this literal part
        if i and segments[i - 1][0] == "ph":
            found = re.finditer(re.escape(part), text)
            starts += [-m.end() for m in found if re.fullmatch(r"\S+", text[:m.start()])]
        for k in starts:
            first = part[-k:] if k > 0 else part
            rest = text[k:] if k > 0 else text[-k:]
            if _rest_fits(rest, segments[i + 1:], weight(first), k < 0):
                return True
    return False


def weight(piece: str) -> int:
    """The characters of a literal piece that count towards MIN_FRAGMENT (not the
    spaces around it)."""
    return len(piece.strip())


def distinctive(piece: str) -> bool:
    piece = piece.strip()
    return len(piece) >= MIN_FRAGMENT and " " in piece


def _rest_fits(rest: str, segments: list[Seg], first: int, in_field: bool) -> bool:
    """Whether ``rest`` continues the message through ``segments`` (fields and literal
    parts in turn; it may end anywhere) with MIN_FRAGMENT literal characters in all
    (``first``: those of the literal piece it began with; ``in_field``: it began inside a
    field). A text that begins or ends inside a field needs MIN_FRAGMENT characters of
    one literal piece."""
    def enough(total: int, longest: int, ends_in_field: bool) -> bool:
        return total >= MIN_FRAGMENT and (
            longest >= MIN_FRAGMENT or not (in_field or ends_in_field))

    if not rest:
        return enough(first, first, False)
    pattern, total, longest = "", first, first
    for kind, part in segments:
        if kind == "ph":
            if enough(total, longest, True) and re.fullmatch(pattern + r"\S{1,80}", rest):
                return True                          # ends inside this field
            pattern += VALUE
            continue
        for t in range(len(part) - 1, 0, -1):      # ends inside this literal part
            w = weight(part[:t])
            if enough(total + w, max(longest, w), False) and rest.endswith(part[:t]) \
                    and re.fullmatch(pattern + re.escape(part[:t]), rest):
                return True
        pattern += re.escape(part)
        total += weight(part)
        longest = max(longest, weight(part))
        if enough(total, longest, False) and re.fullmatch(pattern, rest):
            return True                              # ends with this literal part
    return False


def matching_tests(templates: list[Tpl], index: TestIndex) -> list[str]:
    hits: set[str] = set()
    for tpl in templates:
        for i in index.candidates(tpl):
            text = index.texts[i]
            if not index.files[text] <= hits and fits(text, tpl):
                hits |= index.files[text]
    return sorted(hits)


# -- output ------------------------------------------------------------------------------

def route(rel: str, where: str) -> tuple[str, int]:
    """(section, rank of the route) of a raise site; "other" if no route matches."""
    function = where.split(".")[-1]
    for rank, (pattern, title) in enumerate(ROUTES):
        if fnmatch.fnmatchcase(f"{rel}:{function}", pattern):
            return title, rank
    return "other", len(ROUTES)


def cell(text: str) -> str:
    return " ".join(text.replace("|", "\\|").split())


def catalogue(sites: list[Site], index: TestIndex) -> tuple[str, dict[str, int]]:
    rows: dict[str, dict[str, dict]] = {title: {} for title in SECTIONS}
    counts: dict[str, int] = {title: 0 for title in SECTIONS}
    for site in sorted(sites, key=lambda s: (route(s.rel, s.where)[1], s.rel, s.line)):
        title = route(site.rel, site.where)[0]
        rows.setdefault(title, {})
        counts[title] = counts.get(title, 0) + 1
        tests = matching_tests(site.messages + site.python, index)
        mark = "" if site.family == INPUT_ERROR else f" ({site.cls})"
        for tpl in site.messages:
            message = cell(as_text(tpl)) + mark
            row = rows[title].setdefault(message, {"where": [], "tests": set()})
            where = f"`{site.rel}:{site.where}`"
            if where not in row["where"]:
                row["where"].append(where)
            row["tests"].update(tests)
    lines = [INTRO]
    for title, entries in rows.items():
        if not entries:
            continue
        lines += [f"### {title}", "", "| message (template) | where | matched by a test in |",
                  "|---|---|---|"]
        for message, row in entries.items():
            tests = ", ".join(sorted(row["tests"])) or "—"
            lines.append(f"| {message} | {', '.join(row['where'])} | {tests} |")
        lines.append("")
    return "\n".join(lines).rstrip() + "\n", counts


def main(argv: list[str]) -> int:
    global COMMAND_OPTIONS
    modules = load_modules()
    COMMAND_OPTIONS = command_options(modules)
    sites = find_sites(modules)
    text, counts = catalogue(sites, TestIndex(test_literals()))
    sys.stdout.write(text)
    if "--counts" in argv:
        for title, n in counts.items():
            print(f"{n:4d}  {title}", file=sys.stderr)
        print(f"{sum(counts.values()):4d}  raise sites", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
