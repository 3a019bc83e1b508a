"""docs/architecture.md kept true: the core's layers and imports, and the list of places that adding a
plant state touches (a state is added here, through that list only, and the simulator runs it)."""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

import ambid.plant.true_rig as true_rig
from ambid.plant.rig import make_rig
from ambid.plant.simulator import PlantSimulator

ROOT = Path(__file__).resolve().parents[2]
CORE = ROOT / "ambid_core" / "ambid"
NODES = ROOT / "ambid_nodes" / "ambid_nodes"
CLI = ROOT / "ambid_cli" / "ambid_cli"
DOC = (ROOT / "docs" / "architecture.md").read_text()


def _modules(pkg_dir: Path) -> dict[str, Path]:
    out = {}
    for p in pkg_dir.rglob("*.py"):
        parts = list(p.relative_to(pkg_dir.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


@functools.cache
def _tree(path: Path) -> ast.Module:
    """``path`` parsed, once for the module's tests (each walks every file of the project; read-only)."""
    return ast.parse(path.read_text())


def _imports(mod: str, path: Path, known: dict[str, Path]) -> list[tuple[str, str]]:
    """(imported module, imported name or '') for every import of ``path``, relative ones resolved."""
    out = []
    tree = _tree(path)
    base = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            target = ".".join(base[:len(base) - node.level + 1] + ([node.module] if node.module else [])) \
                if node.level else node.module or ""
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.append((sub, "") if sub in known else (target, a.name))
        elif isinstance(node, ast.Import):
            out += [(a.name, "") for a in node.names]
    return out


CORE_MODULES = _modules(CORE)
NODE_MODULES = _modules(NODES)
CLI_MODULES = _modules(CLI)


def _folder(mod: str) -> str:
    """The room a core module lives in: its subpackage, 'foundation' for the top-level modules, 'api' for the
    public API (ambid.api) and the package's face that hands it on (ambid/__init__.py)."""
    if mod in ("ambid", "ambid.api"):
        return "api"
    parts = mod.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and (CORE / parts[1]).is_dir()) else "foundation"


def _edges() -> dict[str, set[str]]:
    edges: dict[str, set[str]] = {m: set() for m in CORE_MODULES}
    for m, p in CORE_MODULES.items():
        for target, _ in _imports(m, p, CORE_MODULES):
            if target in CORE_MODULES and target != m:
                edges[m].add(target)
    return edges


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_no_import_circles_between_modules_or_folders():
    edges = _edges()
    assert _cycles(edges) == []
    folders: dict[str, set[str]] = {}
    for m, targets in edges.items():
        folders.setdefault(_folder(m), set()).update(_folder(t) for t in targets if _folder(t) != _folder(m))
    assert _cycles(folders) == []


def test_folders_import_only_the_layers_below_them_as_the_document_says():
    m = re.search(r"^Layers, lowest first: (.+)$", DOC, re.M)
    assert m, "docs/architecture.md must state 'Layers, lowest first: ...'"
    layers = [x.strip(" `.") for x in m.group(1).split(",")]
    rooms = {"foundation", "api"} | {p.name for p in CORE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert set(layers) == rooms, "the document's layers must name every folder of ambid/ exactly once"
    rank = {name: i for i, name in enumerate(layers)}
    wrong = [(a, b) for a, targets in _edges().items() for b in targets
             if rank[_folder(b)] > rank[_folder(a)]]
    assert wrong == []


def test_core_never_imports_ros_or_the_nodes():
    for m, p in CORE_MODULES.items():
        for target, _ in _imports(m, p, CORE_MODULES):
            top = target.split(".")[0]
            assert top not in ("rclpy", "rosidl_runtime_py", "ambid_msgs", "ambid_nodes", "ambid_cli"), (m, target)


def _project_edges() -> dict[str, set[str]]:
    """Every import between the modules of core, nodes and command line, those inside functions too."""
    known = {**CORE_MODULES, **NODE_MODULES, **CLI_MODULES}
    edges: dict[str, set[str]] = {m: set() for m in known}
    for m, p in known.items():
        for target, _ in _imports(m, p, known):
            if target in known and target != m:
                edges[m].add(target)
    return edges


def test_no_import_circle_anywhere_in_the_project():
    """No circle between modules of core, nodes and command line (an import inside a function counts: it
    hides a circle from Python's start-up, not from the reader); the core's folders are held above."""
    assert _cycles(_project_edges()) == []


def _layer(mod: str) -> int:
    """0 the core, 1 the nodes, 2 running a session (ambid_nodes.running: its plan and layouts), 3 the command
    line."""
    if mod == "ambid_nodes.running" or mod.startswith("ambid_nodes.running."):
        return 2
    return {"ambid": 0, "ambid_nodes": 1, "ambid_cli": 3}[mod.split(".")[0]]


def test_the_layers_point_one_way_command_line_running_nodes_core():
    """The command line drives sessions through ambid_nodes.running, which starts the nodes, which call the
    core; no import runs back up (a node never imports a layout, whatever the layout imports)."""
    up = [(m, t) for m, targets in _project_edges().items() for t in targets if _layer(t) > _layer(m)]
    assert up == []


def test_running_a_session_imports_only_the_modules_before_it_as_the_document_says():
    """One way to run a session: the modules of ambid_nodes/running/ in the order docs/architecture.md names
    them, each importing only those before it (the layouts share the interface, none imports another back)."""
    m = re.search(r"^Running, lowest first: (.+)$", DOC, re.M)
    assert m, "docs/architecture.md must state 'Running, lowest first: ...'"
    order = [f"ambid_nodes.running.{x.strip(' `.')}" for x in m.group(1).split(",")]
    running = {mod for mod in NODE_MODULES if mod.startswith("ambid_nodes.running.")}
    assert set(order) == running, "the document must name every module of ambid_nodes/running/ exactly once"
    rank = {mod: i for i, mod in enumerate(order)}
    edges = _project_edges()
    wrong = [(a, b) for a in order for b in edges[a] if b in rank and rank[b] >= rank[a]]
    assert wrong == []
    # the command line starts a session through run_session or run_identify, never a layout by itself
    layouts = {f"ambid_nodes.running.{x}" for x in ("composed", "hardware", "processes", "layout")}
    assert [(a, b) for a in CLI_MODULES for b in edges[a] if b in layouts] == []


def test_the_check_sees_an_import_inside_a_function(tmp_path):
    """The circle the nodes once had (graph <-> supervisor) was hidden in a function: the walk finds such."""
    a, b = tmp_path / "pkg" / "a.py", tmp_path / "pkg" / "b.py"
    a.parent.mkdir()
    a.write_text("def f():\n    from pkg.b import g\n    return g\n")
    b.write_text("import pkg.a\n")
    known = {"pkg.a": a, "pkg.b": b}
    edges = {m: {t for t, _ in _imports(m, p, known) if t in known and t != m} for m, p in known.items()}
    assert _cycles(edges) == [["pkg.a", "pkg.b"]]


LONGEST_FUNCTION = 100  # lines from its def to its last line, docstring included


def test_no_function_over_100_lines_in_the_core_or_the_nodes():
    """A long function is split into named stages (docs/architecture.md); this keeps it so."""
    long = []
    for p in list(CORE_MODULES.values()) + list(NODE_MODULES.values()):
        for node in ast.walk(_tree(p)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > LONGEST_FUNCTION:
                    long.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.name} ({n} lines)")
    assert long == []


SESSION_NODES = ("excitation_generator", "frf_consumer", "hardware_bridge", "plant_sim", "position_controller",
                 "recorder")


@pytest.mark.parametrize("name", SESSION_NODES)
def test_a_node_writes_its_reporting_intake_and_main_once_in_session_node(name):
    """Events for rejected, foreign and failed messages, joining the session and main live in
    ambid_nodes/session_node.py; a node file keeps what makes it itself (where it stands, what it logs)."""
    tree = _tree(NODES / f"{name}.py")
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef)
               and any(isinstance(b, ast.Name) and b.id == "SessionNode" for b in n.bases)]
    assert len(classes) == 1, f"{name}.py: one node class, a SessionNode"
    own = {f.name for f in classes[0].body if isinstance(f, ast.FunctionDef)}
    assert not own & {"on_reject", "on_foreign", "on_handler_error", "event", "main"}, own
    assert not any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in tree.body), f"{name}.py writes main"
    text = (NODES / f"{name}.py").read_text()
    assert "Intake(" not in text and "SessionIdentity(" not in text


def test_the_nodes_never_import_the_command_line():
    # imports point one way: command line -> nodes -> core
    for m, p in NODE_MODULES.items():
        for target, _ in _imports(m, p, NODE_MODULES):
            assert target.split(".")[0] != "ambid_cli", (m, target)


def test_no_private_name_crosses_a_folder():
    known = {**CORE_MODULES, **NODE_MODULES, **CLI_MODULES}
    bad = []
    for m, p in known.items():
        for target, name in _imports(m, p, known):
            if target not in known:
                continue
            dunder = name.startswith("__") and name.endswith("__")
            private = (name.startswith("_") and not dunder) or any(part.startswith("_") and part != "__init__"
                                                                   for part in target.split(".")[1:])
            if private and target.rsplit(".", 1)[0] != m.rsplit(".", 1)[0] and not \
                    (target.rsplit(".", 1)[0] == m):  # a package may use its own private modules
                bad.append((m, target, name))
    for p in (ROOT / "tests").rglob("*.py"):  # the tests use the public names too
        for target, name in _imports("tests." + p.stem, p, known):
            if target.split(".")[0] in ("ambid", "ambid_nodes", "ambid_cli") and (
                    (name.startswith("_") and not name.endswith("__"))
                    or any(part.startswith("_") and part != "__init__" for part in target.split(".")[1:])):
                bad.append((str(p.relative_to(ROOT)), target, name))
    assert bad == []


def _section(title: str) -> str:
    m = re.search(rf"^#+ {re.escape(title)}\n(.*?)(?=^#+ |\Z)", DOC, re.M | re.S)
    assert m, f"docs/architecture.md has no section '{title}'"
    return m.group(1)


@pytest.mark.parametrize("title", ["Adding a plant state", "Adding a controller kind"])
def test_the_documents_places_to_change_exist(title):
    text = _section(title)
    places = re.findall(r"`((?:ambid_core|ambid_nodes|docs|tests|launch_scripts)/[\w/.-]+)`(?:[^`\n]*?`(\w+)\(?\)?`)?", text)
    assert places, f"'{title}' names no files"
    for path, name in places:
        f = ROOT / path
        assert f.exists(), f"{title}: {path} does not exist"
        if name and f.suffix == ".py":
            assert re.search(rf"^\s*(def|class) {name}\b|^{name}\b", f.read_text(), re.M), \
                f"{title}: {path} has no {name}"


def _with_anti_alias_state(wa_rad_s: float):
    """true_plant with one more state per channel, added the way the document says: a first-order
    anti-alias filter between the sensor and the ADC (z' = wa (y_old - z), y = z)."""
    original = true_rig.true_plant

    def true_plant(rig, ki=None, ks=None, force_const=None):
        p = original(rig, ki, ks, force_const)
        n = p.a.shape[0]
        grow = lambda m: np.vstack([m, np.zeros((4, m.shape[1]))])  # noqa: E731 - new rows: the filter's
        a = np.block([[p.a, np.zeros((n, 4))], [wa_rad_s * p.c_y, -wa_rad_s * np.eye(4)]])
        wide = lambda c: np.hstack([c, np.zeros((4, 4))])  # noqa: E731 - maps read the old states only
        c_y = np.hstack([np.zeros((4, n)), np.eye(4)])
        return true_rig.TruePlant(a, grow(p.b_u), grow(p.b_f), grow(p.b_s), np.concatenate([p.b_c, np.zeros(4)]),
                                  c_y, wide(p.c_gap), wide(p.c_current), wide(p.c_sensor), p.ki, p.ks,
                                  p.force_const, p.delay_s, p.n_rotor)
    return true_plant


def test_a_plant_state_added_in_true_plant_alone_runs_in_the_simulator(monkeypatch):
    """The list says: the state goes into true_plant(); simulator, step kernel and the true linear model
    follow. Added here, the simulator's step response equals the extended model's, computed by scipy."""
    assert "true_plant" in _section("Adding a plant state")
    rig = make_rig({"sensor_noise_m": 0.0})
    n_steps, step_a = 100, 0.002  # small and short: free flight, clear of the backup bearings

    def responses():
        sim = PlantSimulator(rig)
        sim.start_levitated()
        u0 = sim.operating_point.current_a
        du = np.zeros(4)
        du[0] = step_a
        y = np.empty((n_steps, 4))
        for k in range(n_steps):
            y[k] = sim.output()
            sim.step(u0 + du)
        lin = true_rig.true_linear_model(rig, discrete=True)
        _, y_ref, _ = signal.dlsim((lin.a, lin.b, lin.c, lin.d, lin.dt), np.tile(du, (n_steps, 1)))
        return sim.plant.n_states, y, y_ref

    n_plain, y_plain, _ = responses()
    monkeypatch.setattr(true_rig, "true_plant", _with_anti_alias_state(2 * np.pi * 1500.0))
    n_more, y_more, y_ref = responses()
    assert n_more == n_plain + 4
    scale = np.abs(y_ref).max()
    assert np.abs(y_more - y_ref).max() < 1e-9 * scale
    assert np.abs(y_more - y_plain).max() > 1e-2 * scale  # the new state changes what the sensors read
