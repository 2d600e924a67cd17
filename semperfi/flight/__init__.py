"""Flight-controller side: maneuvers, dead reckoning, MAVLink, the link to the receiver."""

from ..face import lazy_face

# the names other rooms use, by the module that gives them (loaded when first used)
__all__, __getattr__, __dir__ = lazy_face(__name__, {
    "companion": ("serve",),
    "deadreckoning": ("GRAVITY_NED_MPS2", "ins_error_bound_m", "rotation_matrix", "write_track_csv"),
    "link": ("LinkPeer",),
    "maneuver": ("Leg", "ManeuverLimits", "draw", "plan_trajectory"),
    "mavlink_pilot": ("Pilot", "check_vehicle_url"),
})
