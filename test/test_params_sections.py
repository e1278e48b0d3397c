"""Which sections of a ROS params file reach the node: every key form rcl accepts, as rcl applies them (issue 32.2).
test/integration/test_node_params.py checks the same cases against rclpy itself."""

from __future__ import annotations

import pytest

from ros2_mos.core.errors import ConfigError
from ros2_mos.ros.params import fully_qualified_name, load_params_file, read_params_file, section_applies


def _section(key: str, threshold: float) -> str:
    return f"{key}:\n  ros__parameters:\n    threshold: {threshold}\n"


#: (key, nodes it reaches, nodes it does not)
KEYS = [
    ("/robot1/mos_node", ["/robot1/mos_node"], ["/mos_node", "/robot2/mos_node", "/robot1/other"]),
    ("robot1/mos_node", ["/robot1/mos_node"], ["/mos_node"]),
    ("mos_node", ["/mos_node"], ["/robot1/mos_node"]),
    ("/mos_node", ["/mos_node"], ["/robot1/mos_node"]),
    ("/**", ["/mos_node", "/robot1/mos_node", "/a/b/mos_node"], []),
    ("/**/mos_node", ["/mos_node", "/robot1/mos_node", "/a/b/mos_node"], ["/robot1/other"]),
    ("/*/mos_node", ["/robot1/mos_node"], ["/mos_node", "/a/b/mos_node"]),
    ("/robot1/*", ["/robot1/mos_node", "/robot1/other"], ["/mos_node", "/robot2/mos_node"]),
    ("/robot1/**", ["/robot1/mos_node", "/robot1/a/mos_node"], ["/mos_node"]),
    ("/*", ["/mos_node"], ["/robot1/mos_node"]),
    ("/a/**/mos_node", ["/a/b/mos_node", "/a/mos_node"], ["/robot1/mos_node"]),
]


@pytest.mark.parametrize(("key", "reaches", "misses"), KEYS, ids=[k for k, _, _ in KEYS])
def test_a_section_reaches_the_nodes_whose_full_name_it_matches(key, reaches, misses):
    assert all(section_applies(key, node) for node in reaches)
    assert not any(section_applies(key, node) for node in misses)


def test_a_namespaced_node_takes_its_own_section(tmp_path):
    """The issue: `/robot1/mos_node:` (and `/**/mos_node:`) was refused for `-r __ns:=/robot1`."""
    f = tmp_path / "p.yaml"
    for key in ("/robot1/mos_node", "/**/mos_node", "/robot1/*", "/*/mos_node"):
        f.write_text(_section(key, 0.3))
        assert read_params_file(f, "/robot1/mos_node") == ({"threshold": 0.3}, []), key
    # A section rcl would not give to /robot1/mos_node is no section for it: refused, not silently ignored.
    f.write_text(_section("mos_node", 0.3))
    with pytest.raises(ConfigError, match=r"no parameters for node '/robot1/mos_node' \(sections: \['mos_node'\]\); "
                                          r"rcl applies .* key it '/robot1/mos_node', or '/\*\*/mos_node'"):
        load_params_file(f, "/robot1/mos_node")
    # ...and beside a catch-all section it is reported as missed.
    f.write_text(_section("/**", 0.2) + _section("mos_node", 0.3))
    assert read_params_file(f, "/robot1/mos_node") == ({"threshold": 0.2}, ["mos_node"])
    # Sections for other robots in a file shared by several are no concern of this one.
    f.write_text(_section("/robot1/mos_node", 0.3) + _section("/robot2/mos_node", 0.4) + _section("/**", 0.1))
    assert read_params_file(f, "/robot2/mos_node") == ({"threshold": 0.1}, [])


def test_later_sections_win_and_repeated_keys_merge_in_their_first_place(tmp_path):
    """rclpy applies the matching sections in file order; a key written twice is one section, in its first place."""
    f = tmp_path / "p.yaml"
    node = "/robot1/mos_node"
    f.write_text(_section("/robot1/mos_node", 0.1) + _section("/**", 0.2))
    assert load_params_file(f, node) == {"threshold": 0.2}
    f.write_text(_section("/**", 0.2) + _section("/robot1/mos_node", 0.1))
    assert load_params_file(f, node) == {"threshold": 0.1}
    f.write_text(_section("/robot1/mos_node", 0.1) + _section("/**", 0.2) + _section("/robot1/mos_node", 0.3)
                 + "/robot1/mos_node:\n  ros__parameters:\n    min_points: 5\n")
    assert load_params_file(f, node) == {"threshold": 0.2, "min_points": 5}
    f.write_text(_section("robot1/mos_node", 0.1) + _section("/**", 0.2) + _section("/robot1/mos_node", 0.3))
    assert load_params_file(f, node) == {"threshold": 0.3}  # `a` and `/a` are two keys to rcl


def test_a_key_rcl_refuses_is_one_line(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text(_section("/robot*/mos_node", 0.1))
    with pytest.raises(ConfigError, match="is not a node name rcl accepts"):
        load_params_file(f)


def test_fully_qualified_name():
    assert fully_qualified_name() == "/mos_node"
    assert fully_qualified_name("n", "/robot1/") == fully_qualified_name("n", "robot1") == "/robot1/n"
    assert fully_qualified_name("n", "/a/b") == "/a/b/n"
