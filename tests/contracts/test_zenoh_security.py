"""Who may command the vehicle over Zenoh: mutual TLS and access control, on loopback with
a real simulator process and real Zenoh sessions (docs/telemetry.md#security)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import zenoh

from contracts.zenoh_link import (
    TlsIdentity,
    ZenohOptions,
    access_control,
    open_session,
    session_config,
)
from ground.run.children import free_tcp_port
from ground.telemetry.certificates import make_certificates
from ground.uplink.perturb import PerturbationClient, PerturbationError


def test_clear_text_beyond_this_machine_is_refused_unless_asked():
    with pytest.raises(ValueError, match="beyond this machine in clear text.*tls/10.0.0.2"):
        ZenohOptions(connect=["tcp/10.0.0.2:7447"])
    with pytest.raises(ValueError, match="beyond this machine"):
        ZenohOptions("router", listen=["tcp/0.0.0.0:7447"])
    with pytest.raises(ValueError, match="tls needs certificates"):
        ZenohOptions(connect=["tls/127.0.0.1:7447"])
    ZenohOptions(connect=["tcp/127.0.0.1:7447", "tcp/localhost:1", "udp/[::1]:2"])
    ZenohOptions(connect=["tcp/10.0.0.2:7447"], insecure=True)


def test_a_missing_certificate_names_the_file_and_the_command(tmp_path):
    with pytest.raises(ValueError, match=r"ground-key\.pem is missing.*ivfm ground certs"):
        (tmp_path / "ca.pem").write_text("x")
        (tmp_path / "ground.pem").write_text("x")
        TlsIdentity.from_folder(tmp_path, "ground")


def test_the_access_control_admits_queries_only_from_the_commanders():
    acl = access_control(("ground", "gcs-2"))
    assert acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert "query" not in rules["telemetry"]["messages"]
    assert rules["requests"]["messages"] == ["query"]
    subjects = {s["id"]: s for s in acl["subjects"]}
    assert subjects["commanders"]["cert_common_names"] == ["ground", "gcs-2"]
    assert {"rules": ["requests"], "subjects": ["commanders"]} in acl["policies"]


def test_certificates_are_written_with_private_keys_for_the_owner_only(tmp_path):
    files = make_certificates(tmp_path, ("ground", "vehicle"))
    assert sorted(p.name for p in files) == sorted(
        ["ca.pem", "ca-key.pem", "ground.pem", "ground-key.pem", "vehicle.pem",
         "vehicle-key.pem"])
    assert all((p.stat().st_mode & 0o777) == 0o600 for p in files if p.name.endswith("-key.pem"))
    with pytest.raises(ValueError, match="letters, digits"):
        make_certificates(tmp_path, ("a b",))


@pytest.mark.process
def test_only_the_certified_ground_station_commands_the_vehicle(tmp_path):
    certs = tmp_path / "certs"
    make_certificates(certs, ("ground", "vehicle", "intruder"))
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    log = open(tmp_path / "sitl.txt", "w")  # noqa: SIM115
    sim = subprocess.Popen(
        [sys.executable, "-m", "sitl", "--port", str(free_tcp_port()), "--hold",
         "--zenoh-listen", endpoint, "--zenoh-connect", "none", "--zenoh-tls", str(certs),
         "--perturbations"],
        stdout=log, stderr=subprocess.STDOUT)

    def session(identity: str):
        tls = TlsIdentity.from_folder(certs, identity)
        return open_session(ZenohOptions(connect=[endpoint], tls=tls))

    def anonymous_session():
        """TLS that trusts the authority but has no certificate of its own."""
        config = session_config(ZenohOptions())
        config.insert_json5("connect/endpoints", json.dumps([endpoint]))
        config.insert_json5("transport/link/tls",
                            json.dumps({"root_ca_certificate": str(certs / "ca.pem")}))
        return zenoh.open(config)

    def ask_wind(s, timeout_s: float) -> dict | str:
        client = PerturbationClient(session=s, timeout_s=timeout_s)
        try:
            return client.perturb(1, "wind", ned_mps=[3.0, 0.0, 0.0], id="gust")
        except PerturbationError as exc:
            return str(exc)

    try:
        ground = session("ground")
        PerturbationClient(session=ground, timeout_s=60.0).wait_for(1, "sitl")
        # A certificate from the same authority but another name: the vehicle's access
        # control drops the query before the process sees it.
        intruder = session("intruder")
        refused = ask_wind(intruder, 2.0)
        # Plain TCP on the TLS port, and TLS without a certificate: no link at all.
        plain = open_session(ZenohOptions(connect=[endpoint.replace("tls/", "tcp/")]))
        refused_plain = ask_wind(plain, 1.0)
        anonymous = anonymous_session()
        refused_anonymous = ask_wind(anonymous, 1.0)
        client = PerturbationClient(session=ground, timeout_s=10.0)
        assert client.list(1, "sitl") == []  # nothing of theirs arrived
        answer = client.perturb(1, "wind", ned_mps=[1.0, 0.0, 0.0], id="ground-wind")
        listed = client.list(1, "sitl")
        for s in (intruder, plain, anonymous, ground):
            s.close()
    finally:
        sim.terminate()
        sim.wait(30)
        log.close()
    for what in (refused, refused_plain, refused_anonymous):
        assert isinstance(what, str) and what.startswith("no answer from vehicle 1's sitl")
    assert answer["ok"] is True and answer["id"] == "ground-wind"
    assert [p["id"] for p in listed] == ["ground-wind"]
    text = (tmp_path / "sitl.txt").read_text()
    assert "gust" not in text and "ground-wind" in text


@pytest.mark.process
def test_a_vehicle_started_by_hand_refuses_perturbations(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    log = open(tmp_path / "sitl.txt", "w")  # noqa: SIM115
    sim = subprocess.Popen(
        [sys.executable, "-m", "sitl", "--port", str(free_tcp_port()), "--hold",
         "--zenoh-listen", endpoint, "--zenoh-connect", "none"],
        stdout=log, stderr=subprocess.STDOUT)
    try:
        s = open_session(ZenohOptions(connect=[endpoint]))
        client = PerturbationClient(session=s, timeout_s=60.0)
        client.wait_for(1, "sitl")
        with pytest.raises(PerturbationError, match="perturbations are off on this vehicle: "
                                                    "start its processes with --perturbations"):
            client.perturb(1, "wind", ned_mps=[3.0, 0.0, 0.0])
        with pytest.raises(PerturbationError, match="perturbations are off"):
            client.list(1, "sitl")
        s.close()
    finally:
        sim.terminate()
        sim.wait(30)
        log.close()
    assert "perturbation" not in (tmp_path / "sitl.txt").read_text()
