"""`foldcell plan check|reach` through a throwaway parser (the lead wires tools/cli.py)."""

import argparse
import json

from tools.planning_cli import register


def _run(argv, capsys):
    parser = argparse.ArgumentParser(prog="foldcell")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    code = args.func(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_plan_check_json(capsys):
    code, out, _ = _run(["plan", "check", "--category", "towel", "--placements", "1", "--json", "--quiet"],
                        capsys)
    assert code == 0
    report = json.loads(out)
    assert report["towel"]["succeeded"] == 1 and report["towel"]["success_rate"] == 1.0


def test_plan_reach(capsys):
    code, out, _ = _run(["plan", "reach", "0.3", "0.6", "--json"], capsys)
    assert code == 0 and json.loads(out)["reachable"] is True
    code, out, _ = _run(["plan", "reach", "4.0", "0.6"], capsys)
    assert code == 1 and "NOT reachable" in out


def test_bad_input_exits_2(capsys):
    code, _, err = _run(["plan", "check", "--placements", "0"], capsys)
    assert code == 2 and err.startswith("foldcell: error: --placements")
