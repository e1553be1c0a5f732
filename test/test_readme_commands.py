"""Every command the README documents runs as written where this environment allows it.

The README's tour is written for a ROS 2 install (``ros2 run``, ``ros2 launch``,
``ros2 service call``). Here there is no ``ros2`` CLI, so each command is checked the way
that CLI would resolve it:

* ``make X``: X is a target of the Makefile;
* ``ros2 run humanoid_reach_ros EXE ARGS``: EXE is a console entry point of setup.py and is
  installed where ``ros2 run`` looks (``install/.../lib/humanoid_reach_ros``); its ARGS parse
  with the executable's own parser, and commands that finish by themselves (``--help``,
  ``hr_play --info``) are run as installed executables;
* ``$(ros2 pkg prefix humanoid_reach_ros)/share/...``: the file exists in the install space;
* ``ros2 launch humanoid_reach_ros FILE``: the launch file exists and is installed;
* ``ros2 service call /plan_reach TYPE 'YAML'``: the YAML payload is turned into request
  fields as ``ros2 service call`` does (mapping keys -> message fields, recursively) and
  sent to a running reach_planner started with the README's parameter file.

The same holds for docs/operator.md, and every command of both documents runs HERE as written
(``. tools/env.sh``: the executables on ``PATH``, no ``ros2`` CLI, no ``launch``) or is shown
with its here-equivalent beside it: a ``ros2 run humanoid_reach_ros EXE ARGS`` runs here as
``EXE ARGS`` (checked that way), ``ros2 launch ... reach.launch.py`` has ``hr_graph`` beside it,
``ros2 service call /plan_reach`` has ``reach_operator --target``; a command of neither kind
(``hr_graph``, ``reach_planner --ros-args ...``, ``python -m ...``, ``make X``) is checked as
written: installed, its arguments parsed by its own parser, its files there.

Also: the README stays small, its links and picture exist, every path that
docs/paper_map.md names exists, and no file of the repository points outside it.
"""
from __future__ import annotations

import ast
import importlib
import importlib.util
import os
import re
import shlex
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from nodetools import REPO_ROOT

README = REPO_ROOT / "README.md"
OPERATOR_MD = REPO_ROOT / "docs" / "operator.md"
PACKAGE = "humanoid_reach_ros"
INSTALL_PREFIX = REPO_ROOT / "install" / PACKAGE  # what `ros2 pkg prefix humanoid_reach_ros` prints
INSTALLED_EXES = INSTALL_PREFIX / "lib" / PACKAGE
README_MAX_BYTES = 6 * 1024


# ---------------------------------------------------------------- reading the README
def shell_blocks(text: str) -> list[str]:
    """Bodies of the fenced ``bash`` / ``sh`` blocks."""
    return re.findall(r"^```(?:bash|sh)\n(.*?)^```", text, flags=re.S | re.M)


def shell_commands(text: str) -> list[list[str]]:
    """Every command of the shell blocks as argv (continuation lines joined, comments dropped)."""
    out: list[list[str]] = []
    for block in shell_blocks(text):
        pending = ""
        for line in resolve_pkg_prefix(re.sub(r"\\\n", " ", block)).splitlines():
            pending = f"{pending}\n{line}" if pending else line
            try:
                argv = shlex.split(pending, comments=True)
            except ValueError:  # an open quote: the command goes on on the next line, as in the shell
                continue
            pending = ""
            if argv:
                out.append(argv)
        assert not pending, f"unterminated command in the README: {pending!r}"
    return out


def readme_commands() -> list[list[str]]:
    return shell_commands(README.read_text())


def ros2_commands(verb: str) -> list[list[str]]:
    return [c for c in readme_commands() if c[:2] == ["ros2", verb]]


def run_commands(exe: str) -> list[list[str]]:
    """Arguments of every ``ros2 run humanoid_reach_ros EXE ...`` in the README."""
    return [c[4:] for c in ros2_commands("run") if c[2] == PACKAGE and c[3] == exe]


def resolve_pkg_prefix(text: str) -> str:
    """``$(ros2 pkg prefix humanoid_reach_ros)`` -> the install prefix, as the shell would."""
    return text.replace(f"$(ros2 pkg prefix {PACKAGE})", str(INSTALL_PREFIX))


def console_scripts() -> dict[str, str]:
    """setup.py's EXECUTABLES (name -> module:function), read without running setup()."""
    tree = ast.parse((REPO_ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "EXECUTABLES" for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError("setup.py has no EXECUTABLES dict")


def makefile_targets() -> set[str]:
    return set(re.findall(r"^([A-Za-z0-9_.-]+):", (REPO_ROOT / "Makefile").read_text(), flags=re.M)) - {".PHONY"}


# ---------------------------------------------------------------- YAML -> message fields
_FLOATS = {"float", "double", "float32", "float64"}
_INTS = {"int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "byte", "char", "octet"}


def _scalar(base: str, value: Any, where: str) -> Any:
    if base in _FLOATS:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeError(f"{where}: {base} field needs a number, got {value!r}")
        return float(value)
    if base in _INTS:
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError(f"{where}: {base} field needs an integer, got {value!r}")
        return int(value)
    if base == "boolean":
        if not isinstance(value, bool):
            raise TypeError(f"{where}: boolean field needs true/false, got {value!r}")
        return value
    if base in ("string", "wstring") or base.startswith(("string<", "wstring<")):
        if not isinstance(value, str):
            raise TypeError(f"{where}: string field needs a string, got {value!r}")
        return value
    raise TypeError(f"{where}: field type {base!r} is not a scalar")


def _message_class(type_name: str) -> type:
    """``pkg/Name`` or ``pkg/msg/Name`` -> the generated Python class."""
    parts = type_name.split("/")
    pkg, name = parts[0], parts[-1]
    sub = parts[1] if len(parts) == 3 else "msg"
    return getattr(importlib.import_module(f"{pkg}.{sub}"), name)


def set_fields(msg: Any, values: Mapping[str, Any], where: str = "") -> Any:
    """Fill ``msg`` from a YAML mapping the way ``ros2 service call`` / ``ros2 topic pub`` do:
    each key names a field; a mapping fills a nested message, a list an array or sequence;
    fields not named keep their defaults. Unknown fields and wrong types raise with the
    field's path."""
    if not isinstance(values, Mapping):
        raise TypeError(f"{where or type(msg).__name__}: a message needs a mapping, got {values!r}")
    types = msg.get_fields_and_field_types()
    for key, value in values.items():
        path = f"{where}{key}"
        if key not in types:
            raise AttributeError(f"{path}: {type(msg).__name__} has no field {key!r} (fields: {', '.join(types)})")
        t = types[key]
        seq = re.fullmatch(r"sequence<(.+?)(?:, \d+)?>", t)
        arr = re.fullmatch(r"(.+?)\[(<=)?(\d*)\]", t)
        if seq or arr:
            base = seq.group(1) if seq else arr.group(1)
            if not isinstance(value, list):
                raise TypeError(f"{path}: {t} field needs a list, got {value!r}")
            if arr and arr.group(3) and not arr.group(2) and len(value) != int(arr.group(3)):
                raise ValueError(f"{path}: {t} field needs {arr.group(3)} values, got {len(value)}")
            if "/" in base:
                cls = _message_class(base)
                setattr(msg, key, [set_fields(cls(), v, f"{path}[{i}].") for i, v in enumerate(value)])
            else:
                setattr(msg, key, [_scalar(base, v, f"{path}[{i}]") for i, v in enumerate(value)])
        elif "/" in t:
            set_fields(getattr(msg, key), value, f"{path}.")
        else:
            setattr(msg, key, _scalar(t, value, path))
    return msg


def service_request(srv_type: str, payload: str) -> Any:
    """``ros2 service call NAME TYPE PAYLOAD``'s request: TYPE ``pkg/srv/Name``, PAYLOAD YAML."""
    pkg, kind, name = srv_type.split("/")
    if kind != "srv":
        raise ValueError(f"{srv_type!r} is not a service type (pkg/srv/Name)")
    srv = getattr(importlib.import_module(f"{pkg}.srv"), name)
    values = yaml.safe_load(payload)
    return set_fields(srv.Request(), values if values is not None else {})


def plan_reach_call() -> tuple[str, str, str]:
    """The README's ``ros2 service call /plan_reach TYPE PAYLOAD`` (exactly one)."""
    calls = [c for c in ros2_commands("service") if c[2:4] == ["call", "/plan_reach"]]
    assert len(calls) == 1, f"the README should document one /plan_reach call, found {calls}"
    assert len(calls[0]) == 6, calls[0]
    return calls[0][3], calls[0][4], calls[0][5]


# ---------------------------------------------------------------- the README itself
def test_readme_is_small_and_its_links_and_picture_exist() -> None:
    text = README.read_text()
    assert len(README.read_bytes()) <= README_MAX_BYTES, f"README is {len(README.read_bytes())} bytes"
    for heading in ("## Three commands", "## A five-minute tour", "## Where to read on"):
        assert heading in text
    # the heading counts the commands of the block under it
    word, block = re.search(r"^## (\w+) commands\n+```bash\n(.*?)```", text, re.S | re.M).groups()
    numbers = {"one": 1, "two": 2, "three": 3, "four": 4, "five": 5}
    assert numbers[word.lower()] == len([line for line in block.splitlines() if line.strip()]), (word, block)
    assert "make demo" in text and "make test" in text
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    assert any(link.endswith(".png") for link in links), "the README shows a picture"
    for link in links:
        assert "://" not in link and not link.startswith("/"), f"README links outside the repository: {link}"
        assert (REPO_ROOT / link).exists(), f"README links to a missing file: {link}"
    for doc in ("docs/operator.md", "docs/architecture.md", "docs/paper_map.md", "docs/benchmarks.md"):
        assert doc in links


def test_the_tour_covers_run_launch_service_call_operator_and_bags() -> None:
    cmds = readme_commands()
    assert ros2_commands("run") and ros2_commands("launch") and plan_reach_call()
    assert run_commands("reach_operator") and run_commands("hr_play")
    assert any(c[:1] == ["make"] for c in cmds)


TEXT_SUFFIXES = {".md", ".py", ".sh", ".txt", ".yaml", ".yml", ".cfg", ".toml", ".xml", ".ini", ".msg", ".srv",
                 ".action", ".urdf", ".json"}


def _tracked_text_files() -> list[Path]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=REPO_ROOT, capture_output=True, check=True).stdout
    files = [REPO_ROOT / p for p in out.decode().split("\0") if p]
    return [f for f in files if f.is_file() and (f.suffix in TEXT_SUFFIXES or f.name == "Makefile")]


def test_nothing_in_the_repository_points_outside_it() -> None:
    outside = ["../" + "shared", "shared/" + "seeds", "DESIGN" + ".md", "STYLE" + ".md", "/work/" + "main"]
    hits = []
    for f in _tracked_text_files():
        try:
            text = f.read_text()
        except (UnicodeDecodeError, FileNotFoundError):
            continue
        for needle in outside:
            if needle in text:
                hits.append(f"{f.relative_to(REPO_ROOT)}: {needle}")
    assert not hits, "references outside the repository:\n" + "\n".join(hits)


def test_paper_map_names_only_existing_paths() -> None:
    text = (REPO_ROOT / "docs" / "paper_map.md").read_text()
    roots = ("test/", "bench/", "tools/", "doc/", "docs/", "config/", "launch/", f"{PACKAGE}/")
    missing = []
    for token in sorted(set(re.findall(r"`([^`\s]+)`", text))):
        if token.startswith(("/", "~")) or ("/" not in token and not token.endswith(".py")):
            continue  # topics, services, identifiers
        path = REPO_ROOT / token if token.startswith(roots) else REPO_ROOT / PACKAGE / token
        if not path.exists():
            missing.append(token)
    assert not missing, f"docs/paper_map.md names paths that do not exist: {missing}"
    # each of the four source documents has its section
    for heading in ("## K:", "## Y:", "## 003:", "## 004:"):
        assert heading in text


# ---------------------------------------------------------------- make, ros2 run, ros2 launch
def test_make_targets_named_in_the_readme_exist() -> None:
    text = README.read_text()
    named = {c[1] for c in readme_commands() if c[0] == "make" and len(c) > 1}
    named |= set(re.findall(r"`make ([a-z][a-z0-9_-]*)`", text))
    assert {"demo", "test"} <= named
    assert named <= makefile_targets(), f"not Makefile targets: {named - makefile_targets()}"


def test_ros2_run_executables_are_console_entry_points() -> None:
    scripts = console_scripts()
    runs = ros2_commands("run")
    assert runs
    for c in runs:
        assert c[2] == PACKAGE, c
        exe = c[3]
        assert exe in scripts, f"`ros2 run {PACKAGE} {exe}`: no console entry point {exe!r} in setup.py"
        module, func = scripts[exe].split(":")
        assert callable(getattr(importlib.import_module(module), func))
        installed = INSTALLED_EXES / exe
        assert installed.is_file() and os.access(installed, os.X_OK), f"{exe} is not installed at {installed}"


def test_ros2_launch_files_and_params_files_exist() -> None:
    for c in ros2_commands("launch"):
        assert c[2] == PACKAGE
        assert (REPO_ROOT / "launch" / c[3]).is_file(), c
        assert (INSTALL_PREFIX / "share" / PACKAGE / "launch" / c[3]).is_file(), f"{c[3]} is not installed"
    params = [c[c.index("--params-file") + 1] for c in ros2_commands("run")
              if "--params-file" in c]
    assert params, "the README starts a node with its parameter file"
    for p in params:
        assert Path(p).is_file(), f"parameter file {p} does not exist"


# ---------------------------------------------------------------- reach_operator and the bag tools
def test_reach_operator_commands_parse() -> None:
    from humanoid_reach_ros.nodes import reach_operator as op

    cmds = run_commands("reach_operator")
    assert any("--help" in a for a in cmds) and any("--wgr-deg" in a for a in cmds)
    for argv in cmds:
        if "--help" in argv:
            continue  # run as a process below
        args = op.parse_args(argv)
        req = op.plan_request(args)
        if args.wgr is not None:
            assert all(abs(v) <= 3.1416 for v in list(req.region.lower)[3:] + list(req.region.upper)[3:])


def test_reach_operator_help_runs_and_documents_every_flag() -> None:
    """``reach_operator --help`` as installed; every flag docs/operator.md lists is in it."""
    r = subprocess.run([str(INSTALLED_EXES / "reach_operator"), "--help"], cwd=REPO_ROOT, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    help_text = r.stdout
    table = (REPO_ROOT / "docs" / "operator.md").read_text().split("## `reach_operator`", 1)[1].split("\n## ", 1)[0]
    documented = set(re.findall(r"(--[a-z][a-z-]+)", table))
    assert {"--rpy-deg", "--wgr-deg", "--rpy", "--wgr", "--execute", "--json"} <= documented
    missing = {f for f in documented if f not in help_text}
    assert not missing, f"flags documented in docs/operator.md but not in --help: {missing}"
    assert "DEGREES" in help_text


def test_bag_commands_parse_and_info_runs() -> None:
    from humanoid_reach_ros.nodes import bag_play, bag_record

    plays, records = run_commands("hr_play"), run_commands("hr_record")
    assert plays and records
    for argv in records:
        bag_record.parse_args(argv)
    for argv in plays:
        args = bag_play.parse_args(argv)
        assert (REPO_ROOT / args.bag).is_file(), f"the README replays a bag that is not there: {args.bag}"
        if args.info:  # finishes by itself: run it as written
            r = subprocess.run([str(INSTALLED_EXES / "hr_play"), *argv], cwd=REPO_ROOT, capture_output=True,
                               text=True, timeout=60)
            assert r.returncode == 0, r.stderr
            assert "/joint_states" in r.stdout + r.stderr


# ---------------------------------------------------------------- the service call
def test_yaml_setter_fills_fields_like_the_ros2_cli() -> None:
    srv, typ, payload = plan_reach_call()
    assert srv == "/plan_reach" and typ == "humanoid_reach_interfaces/srv/PlanReach"
    req = service_request(typ, payload)
    assert req.region.target.header.frame_id == "world"
    p = req.region.target.pose.position
    assert (p.x, p.y, p.z) == (0.71, 0.03, 0.90)
    assert req.region.target.pose.orientation.w == 1.0  # not named: the default
    assert list(req.region.lower) == [0, 0, 0, -1.5708, -1.5708, -3.1416]
    assert (req.arm, req.goal_count, req.planner, req.time_budget_s, req.execute, req.seed) == \
        (0, 10, "rrt_connect", 2.0, False, -1)
    with pytest.raises(AttributeError, match="region.target.pose.positon"):
        service_request(typ, "{region: {target: {pose: {positon: {x: 1.0}}}}}")
    with pytest.raises(TypeError, match="arm: uint8 field needs an integer"):
        service_request(typ, "{arm: right}")
    with pytest.raises(ValueError, match="region.lower: double\\[6\\] field needs 6 values"):
        service_request(typ, "{region: {lower: [0, 0]}}")
    with pytest.raises(TypeError, match="execute: boolean"):
        service_request(typ, "{execute: 1}")


@pytest.mark.node
def test_readme_service_call_plans_on_a_running_planner(start_node, ros_probe) -> None:
    """The README's ``ros2 run ... reach_planner --ros-args --params-file ...`` then its
    ``ros2 service call /plan_reach ...`` payload, as written (3.1416 included)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from humanoid_reach_interfaces.srv import PlanReach
    from test_reach_planner_node import FAST_DIAG, wait_inputs_ok

    srv, typ, payload = plan_reach_call()
    (planner_args,) = [a for a in run_commands("reach_planner")]
    params_file = planner_args[planner_args.index("--params-file") + 1]
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    start_node("joint_driver", params_file="config/joint_driver.yaml", ready_log=r"simulated hrp2", timeout=60.0)
    # the README's parameter file as written; faster diagnostics and a joint-state timeout that a
    # loaded CI machine cannot trip (the node tests of reach_planner do the same)
    proc = start_node("reach_planner", params_file=params_file, params=FAST_DIAG, ready_log=r"reach planner ready",
                      timeout=120.0)
    client = ros_probe.node.create_client(PlanReach, srv)
    ros_probe.spin_until(client.service_is_ready, 30.0, srv, on_timeout=proc.log_tail)
    wait_inputs_ok(ros_probe, diags, proc)
    from humanoid_reach_ros.codes import ErrorCode as E
    # A loaded 2-core machine may run out of the payload's 2 s budget (or starve the joint-state
    # stream for a moment): those are retried, a request the planner refuses as wrong never is.
    resp = None
    for _ in range(3):
        future = client.call_async(service_request(typ, payload))
        resp = ros_probe.spin_until(lambda future=future: future.done() and future.result(), 60.0,
                                    "a /plan_reach response", on_timeout=proc.log_tail)
        assert resp.error_code.val not in (E.INVALID_REQUEST, E.INVALID_BOUNDS, E.UNKNOWN_FRAME), resp.message
        if resp.error_code.val not in (E.NO_JOINT_STATES, E.NO_GOAL_FOUND, E.NO_PATH):
            break
        wait_inputs_ok(ros_probe, diags, proc)
    assert resp is not None and resp.success and resp.error_code.val == E.SUCCESS, (resp.error_code.val, resp.message)
    assert resp.arm in (PlanReach.Request.ARM_RIGHT, PlanReach.Request.ARM_LEFT)
    assert len(resp.trajectory.points) >= 2 and len(resp.trajectory.joint_names) == 30


# ---------------------------------------------------------------- every command of README.md and docs/operator.md, here
def node_ros_args(argv: list[str], where: str) -> None:
    """``--ros-args [--params-file FILE] [-p name:=value]...``: the file exists (relative to the
    repository: commands run from its root here), each ``-p`` is ``name:=value``."""
    if not argv:
        return
    assert argv[0] == "--ros-args", f"{where}: a node takes --ros-args, got {argv}"
    k = 1
    while k < len(argv):
        if argv[k] == "--params-file":
            f = Path(argv[k + 1])
            assert (f if f.is_absolute() else REPO_ROOT / f).is_file(), f"{where}: no parameter file {f}"
            k += 2
        elif argv[k] == "-p":
            assert ":=" in argv[k + 1], f"{where}: -p needs name:=value, got {argv[k + 1]}"
            k += 2
        else:
            raise AssertionError(f"{where}: unexpected ROS argument {argv[k]!r}")


def check_here(argv: list[str], where: str) -> None:
    """``argv`` runs here as written (see the module doc)."""
    from humanoid_reach_ros import graph_up
    from humanoid_reach_ros.nodes import bag_play, bag_record
    from humanoid_reach_ros.nodes import reach_operator as op

    argv = [a for a in argv if a != "&"]
    exe, args = argv[0], argv[1:]
    scripts = console_scripts()
    if exe == "make":
        assert args and args[0] in makefile_targets(), f"{where}: not a Makefile target: {args}"
    elif exe == ".":
        assert (REPO_ROOT / args[0]).is_file(), f"{where}: {args[0]} does not exist"
    elif exe == "python" and args[:1] == ["-m"]:
        assert importlib.util.find_spec(args[1]) is not None, f"{where}: no module {args[1]}"
        node_ros_args(args[2:], where)
    elif exe in scripts:
        installed = INSTALLED_EXES / exe
        assert installed.is_file() and os.access(installed, os.X_OK), f"{where}: {exe} is not installed"
        parse = {"reach_operator": op.parse_args, "hr_play": bag_play.parse_args, "hr_record": bag_record.parse_args,
                 "hr_graph": graph_up.parse_args}.get(exe)
        if parse is None:   # a node
            assert scripts[exe].startswith(f"{PACKAGE}.nodes."), f"{where}: {exe} is not a node"
            node_ros_args(args, where)
        elif "--help" not in args:
            parsed = parse(args)
            if exe == "hr_play" and Path(parsed.bag).parts[0] == "bags":
                assert (REPO_ROOT / parsed.bag).is_file(), f"{where}: no bag {parsed.bag}"
    else:
        raise AssertionError(f"{where}: {' '.join(argv)!r} cannot run here (no ros2 CLI, no launch) and is "
                             "neither a ros2 command with its here-form beside it nor an installed executable")


@pytest.mark.parametrize("doc", [README, OPERATOR_MD], ids=lambda p: p.name)
def test_every_command_runs_here_or_has_its_here_form_beside_it(doc: Path) -> None:
    text = doc.read_text()
    commands = shell_commands(text)
    assert commands
    for argv in commands:
        where = f"{doc.name}: {' '.join(argv)[:80]}"
        if argv[0] == "ros2":
            verb = argv[1]
            if verb == "run":
                assert argv[2] == PACKAGE, where
                check_here(argv[3:], where)   # here: the same without the prefix
            elif verb == "launch":
                assert (REPO_ROOT / "launch" / argv[3]).is_file(), where
                here = "hr_graph" if argv[3] == "reach.launch.py" else argv[3].removesuffix(".launch.py")
                assert any(c[0] == here for c in commands), f"{where}: no `{here}` beside it"
            elif verb == "service":
                service_request(argv[4], argv[5])   # the payload fills the request
                assert re.search(r"`reach_operator --target [^`]*`|^reach_operator --target", text, re.M), \
                    f"{where}: no `reach_operator --target` beside it"
            else:
                raise AssertionError(f"{where}: ros2 {verb} is not checked here")
        elif argv[0] == "colcon":
            assert any(c[:2] == ["make", "setup"] for c in commands), f"{where}: no `make setup` beside it"
        else:
            check_here(argv, where)


def test_operator_md_counts_the_scan_poses_of_the_config() -> None:
    """"An empty pose list runs `scan_poses_deg` (N yaw/pitch pairs; the last, yaw Y pitch P deg"."""
    cfg = yaml.safe_load((REPO_ROOT / "config" / "reach_executor.yaml").read_text())["/**"]["ros__parameters"]
    flat = cfg["scan_poses_deg"]
    words = {7: "seven", 8: "eight", 9: "nine", 10: "ten", 11: "eleven", 12: "twelve"}
    m = re.search(r"runs `scan_poses_deg` \((\w+) yaw/pitch pairs; the last,\s+yaw (\S+) pitch (\S+) deg",
                  OPERATOR_MD.read_text())
    assert m, "docs/operator.md no longer describes the scan"
    assert m.group(1) == words.get(len(flat) // 2, str(len(flat) // 2)), (m.group(1), len(flat) // 2)
    assert (float(m.group(2)), float(m.group(3))) == (flat[-2], flat[-1])


def test_readme_demo_and_executor_look_for_the_marker_in_one_place() -> None:
    """The README's ``--look``, the demo's aim at the plant's valve and the executor's
    ``marker_look_deg`` (where reach_operator --marker looks when no marker position is known)."""
    from humanoid_reach_ros.demo import aim_head_deg
    from humanoid_reach_ros.execution.config import PARAMETERS
    from humanoid_reach_ros.paths import config_path
    from humanoid_reach_ros.sim.scene import load_scene

    looks = [a[a.index("--look") + 1:a.index("--look") + 3] for a in run_commands("reach_operator") if "--look" in a]
    assert looks, "the README turns the head with --look"
    cfg = yaml.safe_load((REPO_ROOT / "config" / "reach_executor.yaml").read_text())["/**"]["ros__parameters"]
    valve = load_scene(config_path("scenes/plant.yaml")).target.pose[:3, 3]
    aim = aim_head_deg("hrp2", valve)
    for look in looks:
        assert [float(v) for v in look] == list(aim) == PARAMETERS["marker_look_deg"].default \
            == cfg["marker_look_deg"], (look, aim, cfg["marker_look_deg"])
