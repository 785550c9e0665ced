"""The unknown-parameter rule (core/loop/parameter_names.py) without ROS: how a parameter reaches a
node from the ROS command line and parameter files (rcl's node patterns), and which undeclared
names a node reports, with the closest declared name."""

from __future__ import annotations

import difflib

import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.loop.parameter_names import BY_NAME, TO_ALL, TO_PROCESS, find_unknown, given_scopes


def test_given_scopes_tell_a_parameter_given_by_name_from_one_given_to_every_node(tmp_path):
    params = tmp_path / "p.yaml"
    params.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"a": 1, "shared": 1}},
        "/planner": {"ros__parameters": {"b": 1, "shared": 2, "nested": {"c": 1}}},
        "belief_filter": {"ros__parameters": {"d": 1}},
        "ns": {"planner": {"ros__parameters": {"e": 1}}},
        "/*": {"ros__parameters": {"f": 1}},
        "/**/planner": {"ros__parameters": {"j": 1}},
    }))
    args = ["prog", "--ros-args", "--params-file", str(params), "-p", "g:=1", "-p", "planner:h:=1",
            "-p", "belief_filter:i:=1", "--", "-p", "not_ros:=1"]
    assert given_scopes(args, "/planner", own=False) == {
        "a": TO_ALL, "shared": BY_NAME, "b": BY_NAME, "nested.c": BY_NAME, "f": TO_ALL, "g": TO_PROCESS, "h": BY_NAME,
        "j": BY_NAME}
    assert given_scopes(args, "/ns/planner", own=False)["e"] == BY_NAME
    assert given_scopes(args, "/ns/planner", own=False)["j"] == BY_NAME  # /**/planner: any namespace
    assert "f" not in given_scopes(args, "/ns/planner", own=False)  # '*' is one name token
    assert given_scopes(["--ros-args", "-p", "g:=1"], "/planner", own=True) == {"g": BY_NAME}


NAMES = st.sampled_from(["time_budget", "time_budgett", "max_depth", "max_dept", "seed", "sed", "zzz",
                          "qos_overrides./belief.subscription.depth", "model_file"])


@settings(max_examples=200, deadline=None)
@given(nodes=st.lists(st.tuples(st.sets(NAMES, max_size=4),
                                st.dictionaries(NAMES, st.sampled_from([BY_NAME, TO_PROCESS, TO_ALL]), max_size=5)),
                      min_size=1, max_size=3))
def test_find_unknown_rule(nodes):
    """The reporting rule on arbitrary nodes: never a declared name or a QoS override; always a name
    given by name; a name given to the whole process once if no node declares it, else never; a
    wildcard name only as a near miss of the reporting node's own names; every suggestion declared."""
    declared = [sorted(d) for d, _ in nodes]
    given_ = [g for _, g in nodes]
    found = find_unknown(given_, declared)
    everyone = set().union(*map(set, declared))
    for i, (names, scopes) in enumerate(nodes):
        for name, scope in scopes.items():
            if name in names or name.startswith("qos_overrides."):
                assert name not in found[i]
            elif scope == BY_NAME or (scope == TO_PROCESS and len(nodes) == 1):
                assert name in found[i]
            elif name in everyone:
                assert name not in found[i]
            elif scope == TO_ALL:
                assert (name in found[i]) == bool(difflib.get_close_matches(name, declared[i], cutoff=0.85))
        for name, near in found[i].items():
            assert name in scopes and (near == "" or near in names)
    if len(nodes) > 1:
        process_wide = {n for g in given_ for n, s in g.items() if s == TO_PROCESS and not n.startswith("qos_")}
        for name in process_wide - everyone:
            assert sum(name in f for f, g in zip(found, given_, strict=True) if g.get(name) == TO_PROCESS) == 1
