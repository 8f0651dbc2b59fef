"""Docstrings of the public API name arguments that exist.

Three checks, over every public class and function (and the public methods of the classes):
- in an `**Arguments:**` section, the names a bullet (or a `;`-separated part of one)
  defines before its colon are parameters of the callable;
- a keyword written as `` `name=value` `` is a parameter of the callable, of one of its
  methods, or of another public callable (the text then points at that one);
- a concrete class's docstring names what its constructor takes, not its derived
  properties (`Relay`'s said `size` multipliers, the argument being `n`), apart from the
  properties listed in `DESCRIBED_PROPERTIES` that the text describes on purpose.
"""

import importlib
import inspect
import re


MODULES = (
    "nivpjax",
    "nivpjax.compat",
    "nivpjax.scenes",
    "nivpjax.learn",
    "nivpjax.learn.tasks",
    "nivpjax.learn.fault",
    "nivpjax.learn.pretrained",
    "nivpjax.rl",
)
# Derived properties a class's docstring describes: (class name, property).
DESCRIBED_PROPERTIES = {
    ("EmbeddedBETR", "error_order"),
    ("Richardson", "error_order"),
    ("Model", "selection_rows"),
}
# Keywords of something outside nivpjax: an XLA flag, `jax.jit`'s options.
FOREIGN_KEYWORDS = {"xla_cpu_use_fusion_emitters", "compiler_options"}

_TICKED = re.compile(r"`([A-Za-z_]\w*)`")
_KEYWORD = re.compile(r"`([A-Za-z_]\w*)=[^`]*`")
_SECTION = re.compile(r"\*\*Arguments:\*\*(.*?)(?=\n\*\*\w[^*]*:\*\*|\Z)", re.S)


def _public_objects():
    found = {}
    for name in MODULES:
        module = importlib.import_module(name)
        for attr in dir(module):
            obj = getattr(module, attr)
            if attr.startswith("_") or not (inspect.isclass(obj) or inspect.isfunction(obj)):
                continue
            if not getattr(obj, "__module__", "").startswith("nivpjax"):
                continue
            found.setdefault(id(obj), (f"{name}.{attr}", obj))
    return sorted(found.values(), key=lambda item: item[0])


def _callables():
    """(qualified name, callable, its parameters) for the API and the classes' methods."""
    out = []
    for name, obj in _public_objects():
        out.append((name, obj, _parameters(obj)))
        if inspect.isclass(obj):
            for attr, member in vars(obj).items():
                if inspect.isfunction(member) and not attr.startswith("_"):
                    out.append((f"{name}.{attr}", member, _parameters(member)))
    return out


def _parameters(obj):
    try:
        return set(inspect.signature(obj).parameters)
    except (TypeError, ValueError):
        return set()


def _doc(obj):
    return inspect.getdoc(obj) or ""


def _defined_in_arguments_section(doc):
    """Names each bullet of `**Arguments:**` defines: those ticked before a part's colon."""
    names = []
    for section in _SECTION.findall(doc):
        bullets = re.split(r"\n\s*- ", "\n" + section)
        if len(bullets) == 1:  # an inline list: "**Arguments:** `a` (...), `b`, ..."
            names += _TICKED.findall(re.sub(r"\([^()]*(\([^()]*\)[^()]*)*\)", "", section))
            continue
        for bullet in bullets[1:]:
            for part in bullet.split(";"):
                head = part.split(":", 1)[0] if ":" in part else ""
                names += _TICKED.findall(head)
    return names


CALLABLES = _callables()
ALL_PARAMETERS = set().union(*(params for *_, params in CALLABLES))


def test_the_api_is_found():
    names = {name for name, *_ in CALLABLES}
    assert {"nivpjax.Relay", "nivpjax.solve", "nivpjax.rl.StepSizeGymEnv"} <= names
    assert "nivpjax.Scene.solve" in names


def test_arguments_sections_name_parameters():
    missing = {
        name: [a for a in _defined_in_arguments_section(_doc(obj)) if a not in params]
        for name, obj, params in CALLABLES
    }
    missing = {name: names for name, names in missing.items() if names}
    assert not missing, f"arguments documented but not taken: {missing}"


def test_keywords_are_parameters():
    unknown = {}
    for name, obj, params in CALLABLES:
        own = set(params)
        if inspect.isclass(obj):
            methods = [m for m in vars(obj).values() if inspect.isfunction(m)]
            own |= set().union(*(_parameters(m) for m in methods))
        known = own | ALL_PARAMETERS | FOREIGN_KEYWORDS
        if found := [k for k in _KEYWORD.findall(_doc(obj)) if k not in known]:
            unknown[name] = found
    assert not unknown, f"keywords no public callable takes: {unknown}"


def test_classes_name_their_arguments_not_their_properties():
    derived = {}
    for name, obj, params in CALLABLES:
        if not inspect.isclass(obj) or inspect.isabstract(obj):
            continue
        properties = {n for n, v in inspect.getmembers(obj) if isinstance(v, property)}
        named = set(_TICKED.findall(_doc(obj))) & properties - params
        if found := sorted(p for p in named if (obj.__name__, p) not in DESCRIBED_PROPERTIES):
            derived[name] = found
    assert not derived, f"docstrings naming derived properties, not arguments: {derived}"


def test_the_checks_catch_the_old_relay_docstring():
    doc = "Relay as `size` multipliers. `equation=True` scales.\n\n**Arguments:**\n\n- `size`: n"
    assert _defined_in_arguments_section(doc) == ["size"]
    assert _KEYWORD.findall(doc) == ["equation"] and "equation" not in ALL_PARAMETERS
