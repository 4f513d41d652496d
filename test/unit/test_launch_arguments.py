"""Issue 48: the launch scripts check ``--method`` before a graph starts, against the one method
registry (an unknown name once started the graph, whose planner died at start-up while the launcher
waited), and their ``--help`` lists every method the ROS nodes serve."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

from nbv_prob_cnn.planners import registry

SCRIPTS = Path(__file__).resolve().parents[2] / "launch_scripts"


def load_script(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"launch_{name}", SCRIPTS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def served_methods() -> list[str]:
    """The registry's methods without the oracles (the ROS nodes have no ground truth)."""
    return [name for name, spec in registry.METHODS.items() if not spec.needs_ground_truth]


def parse(script: str, argv: list[str]):
    """The script's argument parsing only (plan_from_bag.py parses in main, and stops at its bag)."""
    module = load_script(script)
    if script == "plan_from_bag":
        return module.main([*argv, "--bag", "/nonexistent/bag"])
    return module.parse_args(argv)


@pytest.mark.parametrize("script", ["explore_sim", "plan_from_bag", "robot"])
def test_an_unknown_method_is_refused_before_the_graph_starts(script, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        parse(script, ["--method", "cnnprob"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "argument --method" in err and "'cnnprob'" in err, err
    for name in served_methods():
        assert f"'{name}'" in err, (name, err)
    assert "'omniscient'" not in err  # an oracle: no ROS node serves it


@pytest.mark.parametrize("script", ["explore_sim", "plan_from_bag", "robot"])
def test_help_lists_every_method_the_nodes_serve(script, capsys) -> None:
    with pytest.raises(SystemExit):
        parse(script, ["--help"])
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps the help
    for name in served_methods():
        assert name in text, (name, text)


@pytest.mark.parametrize("script", ["explore_sim", "plan_from_bag", "robot"])
def test_the_method_choices_are_read_from_the_registry(script, monkeypatch) -> None:
    """A method added to the registry is accepted at once (no list of the script's own), while
    a name it lacks is refused."""
    added = dataclasses.replace(registry.METHODS["prob_ig"], name="added_for_test")
    monkeypatch.setitem(registry.METHODS, "added_for_test", added)
    if script == "plan_from_bag":
        assert parse(script, ["--method", "added_for_test"]) == 2  # parsed; then the missing bag is refused
    else:
        assert parse(script, ["--method", "added_for_test"]).method == "added_for_test"
    monkeypatch.delitem(registry.METHODS, "added_for_test")
    with pytest.raises(SystemExit):
        parse(script, ["--method", "added_for_test"])


def test_the_launchers_exit_codes_are_documented() -> None:
    from nbv_prob_cnn.ros.graph import EXIT_INTERRUPTED, EXIT_NODE_EXITED, EXIT_TIMED_OUT

    readme = (SCRIPTS.parent / "README.md").read_text()
    section = " ".join(readme[readme.index("### Exit codes") :].split("\n## ", 1)[0].split())
    assert f"`{EXIT_NODE_EXITED}` a node exited" in section
    assert f"`{EXIT_TIMED_OUT}` `--timeout` passed" in section
    assert f"`{EXIT_INTERRUPTED}` Ctrl-C" in section
    # distinct from 0-2 and from 3, the nbv commands' empty result
    assert len({EXIT_NODE_EXITED, EXIT_TIMED_OUT, EXIT_INTERRUPTED, 0, 1, 2, 3}) == 7
    for script in ("explore_sim", "plan_from_bag", "robot"):
        assert f"{EXIT_NODE_EXITED} a node exited" in (SCRIPTS / f"{script}.py").read_text()


@pytest.mark.parametrize("script", ["explore_sim", "plan_from_bag", "robot"])
def test_timeout_reaches_the_watch_of_the_whole_run(script, monkeypatch, tmp_path) -> None:
    """``--timeout`` is handed to run_graph, which bounds the whole run with it (the clients' own
    waits for the graph are longer: 300 s); its watching is tested in test/ros/test_node_exits.py."""
    module = load_script(script)
    seen: dict = {}

    def fake_run_graph(start_nodes, client_cmd, env, log_dir, label="graph", timeout_s=None) -> int:
        seen.update(client=client_cmd, timeout_s=timeout_s)
        return 0

    monkeypatch.setattr(module, "run_graph", fake_run_graph)
    argv = ["--timeout", "7", "--out", str(tmp_path)]
    if script == "plan_from_bag":
        argv += ["--bag", str(SCRIPTS.parent / "bags" / "3dt_seed1000_sample")]
    if script == "robot":
        argv += ["--views", "1"]
    assert module.main(argv) == 0
    assert seen["timeout_s"] == 7.0 and seen["client"]
