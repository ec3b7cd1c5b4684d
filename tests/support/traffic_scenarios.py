"""Variants of the shipped antipodal scenario with its obstacles delivered the field's ways."""

from __future__ import annotations

from pathlib import Path

ANTIPODAL = Path(__file__).resolve().parents[2] / "configs" / "antipodal.toml"
_VEL_COV = "velocity_cov_m2ps2 = [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.01]]"

#: name -> the keys added to each obstacle (cycled over the three).
TRANSPORTS: dict[str, list[str]] = {
    "adsb": ['transport = "adsb"'],
    "odometry_clocks": [
        'message = "ODOMETRY"\nclock_offset_s = -100.0\nclock_drift = 0.01',
        'message = "ODOMETRY"\nclock_offset_s = 5.5\nclock_drift = 0.01',
        'message = "ODOMETRY"\nclock_offset_s = 100.0\nclock_drift = 0.01',
    ],
    "remote_id": [f'message = "OPEN_DRONE_ID_LOCATION"\n{_VEL_COV}'],
    "utm": [f'message = "UTM_GLOBAL_POSITION"\n{_VEL_COV}'],
    "local_position_ned": ['message = "LOCAL_POSITION_NED"'],
    "garbage_stamp": ['message = "LOCAL_POSITION_NED"\ngarbage_stamp_at_s = 6.0', 'message = "ODOMETRY"',
                      'message = "ODOMETRY"\ngarbage_stamp_at_s = 7.0'],
    "reboot": ['message = "ODOMETRY"\nclock_offset_s = 300.0\nclock_reboot_at_s = 6.0', 'message = "ODOMETRY"',
               'message = "LOCAL_POSITION_NED"\nclock_offset_s = 50.0\nclock_reboot_at_s = 7.0'],
    "same_socket_odometry": ['transport = "api"'],
}
_ACCURACY = '[traffic]\nposition_std_m = 0.15   # LOCAL_POSITION_NED carries none: the perception source is this good\nvertical_std_m = 0.15\n'
_TRAFFIC = {"same_socket_odometry": '[traffic]\nautopilot_link_kinds = ["ADSB_VEHICLE", "ODOMETRY"]\n',
            "garbage_stamp": _ACCURACY, "reboot": _ACCURACY}


def antipodal_variant(name: str, directory: Path) -> Path:
    """Write the antipodal scenario with transport ``name`` (see :data:`TRANSPORTS`) and return its path."""
    text = ANTIPODAL.read_text()
    head, *obstacles = text.split("[[world.obstacles]]\n")
    if name in _TRAFFIC and "\n[traffic]\n" in head:  # the variant's own [traffic] replaces the shipped one
        start = head.index("\n[traffic]\n") + 1
        end = head.index("\n[", start) + 1
        head = head[:start] + head[end:]
    extra = TRANSPORTS[name]
    out = head.rstrip() + "\n" + _TRAFFIC.get(name, "") + "\n"
    for i, body in enumerate(obstacles):
        body = "".join(line for line in body.splitlines(keepends=True) if not line.startswith(("transport =", "message =")))
        out += "[[world.obstacles]]\n" + extra[i % len(extra)] + "\n" + body
    path = Path(directory) / f"antipodal_{name}.toml"
    path.write_text(out)
    return path
