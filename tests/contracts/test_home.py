"""Home anywhere on Earth: the projection around home (checked against the sphere's own
great-circle distance and bearing, written here independently), ``--home`` parsing, the
world magnetic model, and an autopilot taking home from the simulator's first message."""

from __future__ import annotations

import math

import numpy as np
import pytest

from contracts.frames import DEFAULT_HOME, EARTH_RADIUS_M, Home

PLACES = {"equator": Home(0.0, 0.0, 0.0), "60N": Home(60.0, 10.0, 100.0),
          "45S": Home(-45.0, 170.0, 50.0), "antimeridian": Home(-17.0, 179.9995, 5.0)}


def great_circle(lat1, lon1, lat2, lon2) -> tuple[float, float]:
    """(distance m, initial bearing rad) on the sphere: haversine and the forward azimuth."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dl = math.radians(lon2 - lon1)
    h = math.sin((p2 - p1) / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    distance = 2 * EARTH_RADIUS_M * math.asin(math.sqrt(h))
    bearing = math.atan2(math.sin(dl) * math.cos(p2),
                         math.cos(p1) * math.sin(p2) - math.sin(p1) * math.cos(p2) * math.cos(dl))
    return distance, bearing


@pytest.mark.parametrize("place", PLACES)
@pytest.mark.parametrize("north, east", [(3.0, 4.0), (-800.0, 150.0), (2500.0, -4000.0),
                                         (0.0, 5000.0)])
def test_positions_keep_their_distance_and_bearing_from_home(place, north, east):
    home = PLACES[place]
    lat, lon, alt = home.geodetic_from_ned(north, east, -7.0)
    assert -180.0 <= lon < 180.0 and alt == home.alt_amsl_m + 7.0
    distance, bearing = great_circle(home.lat_deg, home.lon_deg, lat, lon)
    assert distance == pytest.approx(math.hypot(north, east), abs=1e-6)
    assert math.remainder(bearing - math.atan2(east, north), math.tau) == pytest.approx(
        0.0, abs=1e-9)
    back = home.ned_from_geodetic(lat, lon, alt)
    assert np.allclose(back, (north, east, -7.0), atol=1e-6)


def test_east_of_the_antimeridian_is_west_longitude():
    home = PLACES["antimeridian"]
    lat, lon, _ = home.geodetic_from_ned(0.0, 500.0, 0.0)
    assert lon < -179.99  # wrapped, not 180.004
    assert home.ned_from_geodetic(lat, lon, 0.0)[1] == pytest.approx(500.0, abs=1e-6)


@pytest.mark.parametrize("text, message", [
    ("91,0,0", "latitude"), ("nan,0,0", "latitude"), ("0,181,0", "longitude"),
    ("0,0,20000", "altitude"), ("1,2", "three numbers"), ("a,b,c", "three numbers")])
def test_a_bad_home_is_refused_with_what_is_wrong(text, message):
    with pytest.raises(ValueError, match=message):
        Home.parse(text)


def test_home_parses_and_the_scenario_key_is_checked(tmp_path):
    from ground.scenario.scenario_file import scenario_from_dict

    assert Home.parse("-33.86,151.21,3") == Home(-33.86, 151.21, 3.0)
    base = {"name": "h", "reference": {"kind": "hover", "altitude_m": 1.0}}
    assert scenario_from_dict(base, tmp_path / "h.toml", tmp_path).home == DEFAULT_HOME
    placed = scenario_from_dict({**base, "plant": {"home": [60, 10, 100]}}, tmp_path / "h.toml",
                                tmp_path)
    assert placed.home == Home(60.0, 10.0, 100.0)
    with pytest.raises(ValueError, match="plant.home"):
        scenario_from_dict({**base, "plant": {"home": [95, 0, 0]}}, tmp_path / "h.toml",
                           tmp_path)


def test_the_field_comes_from_the_world_magnetic_model_at_home():
    """WMM2025 at MAG_MODEL_YEAR: Zurich's declination is about 3.6 deg east and its field
    dips 63.5 deg; the field differs from place to place and the estimator's declination
    is the field's own."""
    n, e, d = DEFAULT_HOME.mag_field_ned_gauss()
    assert math.degrees(DEFAULT_HOME.mag_declination_rad()) == pytest.approx(3.61, abs=0.05)
    assert math.degrees(math.atan2(d, math.hypot(n, e))) == pytest.approx(63.5, abs=0.1)
    assert math.sqrt(n * n + e * e + d * d) == pytest.approx(0.484, abs=0.002)
    fields = {p: h.mag_field_ned_gauss() for p, h in PLACES.items()}
    assert fields["45S"][2] < 0 < fields["60N"][2]  # the field points up in the south
    from autopilot.estimation.estimator import Estimator

    est = Estimator(home=PLACES["45S"])
    assert np.array_equal(est.field_ned, fields["45S"])
    assert est.declination_rad == PLACES["45S"].mag_declination_rad()


def test_the_autopilot_takes_home_from_the_simulators_first_position():
    """No home given: the first HIL_STATE_QUATERNION is home (as PX4's simulator_mavlink),
    whatever the vehicle flies on (here ODOMETRY); later positions are around it, and
    HOME_POSITION and GLOBAL_POSITION_INT say where on Earth the vehicle is."""
    from autopilot.mavlink.telemetry import telemetry_message
    from contracts.mavlink import mavlink
    from tests.sitl.test_sim_link import _autopilot_on_a_socket, _send_samples

    autopilot, theirs = _autopilot_on_a_socket(home=None)
    assert autopilot.sim.home is None and not autopilot.vehicle.home_known
    _send_samples(theirs, [0, 10_000], kinds=("HIL_SENSOR", "HIL_STATE_QUATERNION"))
    autopilot._on_sim_readable()
    home = autopilot.sim.home
    assert autopilot.vehicle.home_known and autopilot.vehicle.places.origin == home
    assert np.max(np.abs(autopilot.latest[1][0:3])) < 0.01  # the vehicle is at home
    msg = telemetry_message(mavlink.MAVLINK_MSG_ID_HOME_POSITION, autopilot.vehicle, "px4", 0)
    assert (msg.latitude, msg.longitude) == (round(home.lat_deg * 1e7),
                                             round(home.lon_deg * 1e7))


def _sample_with_an_erring_fix(time_us: int, kinds: tuple[str, ...]) -> bytes:
    """One sample from a vehicle standing at DEFAULT_HOME whose GPS fix is 0.5 m north and
    0.4 m low (a receiver's error), its messages in the order our simulator sends them:
    HIL_GPS first."""
    from contracts.mavlink import mavlink
    from contracts.sim_samples import sample_messages
    from sitl.plant import VehicleState
    from sitl.truth import ideal_readings

    at_rest = VehicleState(time_us * 1e-6, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3),
                           np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))
    truth, sensor, fix = ideal_readings(time_us, at_rest, np.zeros(3))
    lat, lon, alt = DEFAULT_HOME.geodetic_from_ned(0.5, 0.0, 0.4)
    fix = fix._replace(lat_deg=lat, lon_deg=lon, alt_amsl_m=alt)
    mav = mavlink.MAVLink(None, 1, 51)
    return b"".join(m.pack(mav) for m in sample_messages(truth, sensor, fix, DEFAULT_HOME)
                    if m.get_type() in kinds)


def test_home_comes_from_the_truth_even_when_a_fix_comes_first():
    """The simulator's HIL_STATE_QUATERNION is home, not the GPS fix sent before it in the
    same sample: the fix's error would put a vehicle standing on the ground 0.4 m up (where
    arming is refused) and half a metre from where it stands."""
    from tests.sitl.test_sim_link import _autopilot_on_a_socket

    autopilot, theirs = _autopilot_on_a_socket(source="estimator", home=None)
    theirs.sendall(_sample_with_an_erring_fix(0, ("HIL_GPS",)))
    autopilot._on_sim_readable()
    assert autopilot.sim.home is None  # a fix alone does not settle home at once
    theirs.sendall(_sample_with_an_erring_fix(10_000, ("HIL_GPS", "HIL_SENSOR",
                                                       "HIL_STATE_QUATERNION")))
    autopilot._on_sim_readable()
    assert autopilot.vehicle.home_known
    home = autopilot.vehicle.places.origin
    assert np.allclose(home, DEFAULT_HOME, rtol=0, atol=1e-6)  # e7 degrees, mm altitude
    assert "HIL_STATE_QUATERNION" in autopilot.sim.home_source


def test_a_simulator_without_truth_gives_home_from_its_first_fix():
    """No HIL_STATE_QUATERNION: home is the first 3D fix, once fixes have come for
    HOME_FROM_GPS_AFTER_US without one."""
    from autopilot.process.sim_link import HOME_FROM_GPS_AFTER_US
    from tests.sitl.test_sim_link import _autopilot_on_a_socket

    autopilot, theirs = _autopilot_on_a_socket(source="estimator", home=None)
    for t in range(0, HOME_FROM_GPS_AFTER_US, 100_000):
        theirs.sendall(_sample_with_an_erring_fix(t, ("HIL_GPS", "HIL_SENSOR")))
        autopilot._on_sim_readable()
        assert autopilot.sim.home is None
    theirs.sendall(_sample_with_an_erring_fix(HOME_FROM_GPS_AFTER_US, ("HIL_GPS", "HIL_SENSOR")))
    autopilot._on_sim_readable()
    home = autopilot.vehicle.places.origin
    assert autopilot.vehicle.home_known and "first GPS fix" in autopilot.sim.home_source
    north, east, down = DEFAULT_HOME.ned_from_geodetic(*home)
    assert (north, east, down) == pytest.approx((0.5, 0.0, 0.4), abs=0.01)


def test_named_homes_by_any_case_and_a_bad_name_lists_them():
    from contracts.frames import NAMED_HOMES, named_home

    assert named_home("CMAC") == named_home("cmac") == Home(-35.363261, 149.16523, 584.0)
    assert named_home("px4") == DEFAULT_HOME
    assert named_home("-35.5,149.5,600") == Home(-35.5, 149.5, 600.0)
    with pytest.raises(ValueError, match="neither LAT,LON,ALT nor a named home") as err:
        named_home("Atlantis")
    assert all(name in str(err.value) for name in NAMED_HOMES)


@pytest.mark.process
def test_the_simulator_refuses_a_bad_home_name_before_it_starts():
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "sitl", "--home", "Atlantis"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "'Atlantis' is neither LAT,LON,ALT nor a named home (PX4, CMAC" in done.stderr
