"""The demo's ROS domain: ``--domain-id``, else the exported ``ROS_DOMAIN_ID``, else a random one in
1..101; a bad value is one line naming where it came from (also from the command line)."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from pomdp_planner.core.errors import OptionError
from pomdp_planner.nodes import demo


def test_the_exported_domain_is_used_and_the_option_wins():
    assert demo.choose_domain_id(None, {"ROS_DOMAIN_ID": "42"}) == (42, "ROS_DOMAIN_ID")
    assert demo.choose_domain_id(None, {"ROS_DOMAIN_ID": " 0 "}) == (0, "ROS_DOMAIN_ID")
    assert demo.choose_domain_id(7, {"ROS_DOMAIN_ID": "42"}) == (7, "--domain-id")


def test_random_only_when_unset():
    for env in ({}, {"ROS_DOMAIN_ID": ""}):
        seen = {demo.choose_domain_id(None, env) for _ in range(200)}
        assert {source for _, source in seen} == {"random"}
        assert all(1 <= d <= 101 for d, _ in seen) and len(seen) > 1


@pytest.mark.parametrize("given, env, match", [
    (None, {"ROS_DOMAIN_ID": "x1"}, r"ROS_DOMAIN_ID: must be an integer 0..232, got 'x1'"),
    (None, {"ROS_DOMAIN_ID": "300"}, r"ROS_DOMAIN_ID: must be an integer 0..232, got 300"),
    (-1, {}, r"--domain-id: must be an integer 0..232, got -1")])
def test_a_bad_domain_is_one_line(given, env, match):
    with pytest.raises(OptionError, match=match):
        demo.choose_domain_id(given, env)


def test_the_command_line_refuses_a_bad_exported_domain(monkeypatch, capsys):
    monkeypatch.setenv("ROS_DOMAIN_ID", "abc")
    with pytest.raises(SystemExit) as exc:
        demo.main(["--steps", "1"])
    assert exc.value.code == 2
    assert "ROS_DOMAIN_ID: must be an integer 0..232, got 'abc'" in capsys.readouterr().err
