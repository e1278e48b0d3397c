"""The shipped Fast DDS profile: valid, installed, and never overriding the user's choice."""

import xml.etree.ElementTree as ET

from ros2_mos.ros.dds import PROFILE_VARIABLES, profile_path, use_large_message_profile

NS = {"p": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def test_profile_is_shipped_and_sets_a_32_mb_shared_memory_segment_plus_udp():
    root = ET.parse(profile_path()).getroot()
    transports = {
        d.findtext("p:transport_id", namespaces=NS): d for d in root.iterfind(".//p:transport_descriptor", NS)
    }
    shm = [d for d in transports.values() if d.findtext("p:type", namespaces=NS) == "SHM"]
    assert len(shm) == 1 and int(shm[0].findtext("p:segment_size", namespaces=NS)) == 32 * 1024 * 1024
    participant = root.find(".//p:participant", NS)
    assert participant.get("is_default_profile") == "true"
    used = [t.text for t in participant.iterfind(".//p:userTransports/p:transport_id", NS)]
    assert set(used) == set(transports)  # every declared transport is used, UDP included
    assert participant.findtext(".//p:useBuiltinTransports", namespaces=NS) == "false"


def test_profile_is_set_in_an_empty_environment():
    env: dict[str, str] = {}
    assert use_large_message_profile(env)
    assert all(env[v] == str(profile_path()) for v in PROFILE_VARIABLES)


def test_the_users_profile_or_middleware_wins():
    own = {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/my_profile.xml"}
    assert not use_large_message_profile(own)
    assert own == {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/my_profile.xml"}
    cyclone = {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}
    assert not use_large_message_profile(cyclone)
    assert cyclone == {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}
