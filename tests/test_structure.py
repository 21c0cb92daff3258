"""The house's rules (docs/design.md): no import circles, no import up the floors, no import hidden
inside a function except the few that must wait (each says why), and no module or class so large that a
change has no obvious room (the few exceptions listed with their reasons)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "thermal_wild_ns"
FLOORS = [
    ["errors", "progress", "image_metrics", "decisions", "state_names", "install"],
    ["_upstream"],
    ["data"],
    ["preprocessing"],
    ["pipeline", "analysis"],
    ["rendering", "export", "training"],
    ["model"],
    ["method_configs"],
    ["demo", "multi_gpu"],
]
"""Rooms bottom up, as docs/design.md draws them: a module may import its own floor's and lower ones."""
FUNCTION_LOCAL_IMPORTS = {
    "pycolmap": "the light GPU install has no pycolmap",
    "jpeg_ls": "the light GPU install may have no pyjpegls: only FLIR files compressed as JPEG-LS need it",
    "nerfstudio.scripts": "command scripts (the exporter needs open3d, absent from the light install)",
    "numpy.core.multiarray": "private numpy names, only for the checkpoint allow-list",
    "imageio_ffmpeg": "optional",
    "rasterio": "only a georeferenced survey's export needs it (GDAL, PROJ); the GPU image's bundle has none",
    "torch": "the torchvision shim loads at interpreter start, before torch is wanted",
}
"""The only imports allowed inside functions, and why."""
MODULE_LINES = 500
CLASS_LINES = 400
LARGER: dict[str, str] = {}
"""Package modules allowed past `MODULE_LINES` lines, and why."""


def module_name(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        yield module_name(path), ast.parse(path.read_text())


def imported(node):
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    return [node.module] if node.level == 0 and node.module else []


def floor(module: str) -> int:
    room = module.split(".")[1] if "." in module else ""
    return next(i for i, rooms in enumerate(FLOORS) if room in rooms)


def package_imports():
    graph = {}
    for name, tree in modules():
        graph[name] = {
            target
            for node in tree.body
            if isinstance(node, (ast.Import, ast.ImportFrom))
            for target in imported(node)
            if target.startswith("thermal_wild_ns.")
        }
    return graph


def local_imports(name: str, tree: ast.AST) -> list:
    """Imports inside functions or classes of module `name` that `FUNCTION_LOCAL_IMPORTS` does not list."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            for sub in ast.walk(node):
                if isinstance(sub, (ast.Import, ast.ImportFrom)):
                    for target in imported(sub) or ["(relative)"]:
                        if not any(target == m or target.startswith(m + ".") for m in FUNCTION_LOCAL_IMPORTS):
                            found.append(f"{name}:{sub.lineno} imports {target}")
    return sorted(set(found))


def upward_imports(graph: dict) -> list:
    return [
        f"{name} (floor {floor(name)}) -> {target} (floor {floor(target)})"
        for name, targets in graph.items()
        if name != "thermal_wild_ns"
        for target in targets
        if floor(target) > floor(name)
    ]


def circles(graph: dict) -> list:
    state, found = {}, []

    def visit(node, path):
        state[node] = "open"
        for target in graph.get(node, ()):
            if state.get(target) == "open":
                found.append(" -> ".join(path[path.index(target) :] + [target]))
            elif target not in state:
                visit(target, path + [target])
        state[node] = "done"

    for node in graph:
        if node not in state:
            visit(node, [node])
    return found


def oversized(name: str, source: str) -> list:
    """What in module `name` (its `source`) is past the size rules: the module past `MODULE_LINES` lines (unless
    `LARGER` lists it), a class past `CLASS_LINES`."""
    found = []
    lines = len(source.splitlines())
    if lines > MODULE_LINES and name not in LARGER:
        found.append(f"{name}: {lines} lines (at most {MODULE_LINES}: split it by what changes together)")
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > CLASS_LINES:
            found.append(f"{name}.{node.name}: {node.end_lineno - node.lineno + 1} lines (at most {CLASS_LINES})")
    return found


def test_no_module_or_class_past_its_size_but_the_listed_ones():
    found = [line for path in sorted(PACKAGE.rglob("*.py")) for line in oversized(module_name(path), path.read_text())]
    assert not found, "\n".join(found)
    assert set(LARGER) <= {module_name(path) for path in PACKAGE.rglob("*.py")}, "a listed exception no longer exists"


def test_no_import_inside_a_function_but_the_listed_ones():
    found = [line for name, tree in modules() for line in local_imports(name, tree)]
    assert not found, "\n".join(found)


def test_no_import_runs_up_a_floor():
    upward = upward_imports(package_imports())
    assert not upward, "\n".join(upward)


def test_no_import_circles():
    found = circles(package_imports())
    assert not found, "\n".join(found)


def test_the_rules_find_what_they_look_for():
    """On made-up code: a hidden import, an import up a floor and a circle are each reported."""
    source = "import os\ndef f():\n    import pycolmap\n    from thermal_wild_ns.model import fields\n"
    assert local_imports("m", ast.parse(source)) == ["m:4 imports thermal_wild_ns.model"]
    data, model = "thermal_wild_ns.data.layouts", "thermal_wild_ns.model.fields"
    assert upward_imports({data: {model}, model: {data}}) == [f"{data} (floor 2) -> {model} (floor 6)"]
    assert circles({data: {model}, model: {data}}) == [f"{data} -> {model} -> {data}"]
    assert circles({data: {model}, model: set()}) == []
    body = "x = 1\n" * MODULE_LINES
    assert oversized("thermal_wild_ns.data.m", body) == []
    assert oversized("thermal_wild_ns.data.m", body + "y = 2\n") == [
        f"thermal_wild_ns.data.m: {MODULE_LINES + 1} lines (at most {MODULE_LINES}: split it by what changes together)"
    ]
    LARGER["thermal_wild_ns.data.m"] = "a reason"  # a module listed with its reason may grow past the limit
    try:
        assert oversized("thermal_wild_ns.data.m", body + "y = 2\n") == []
    finally:
        del LARGER["thermal_wild_ns.data.m"]
    big_class = "class Hub:\n" + "    x = 1\n" * CLASS_LINES
    assert oversized("thermal_wild_ns.model.m", big_class) == [
        f"thermal_wild_ns.model.m.Hub: {CLASS_LINES + 1} lines (at most {CLASS_LINES})"
    ]
