"""The world SemperFi is proven against: constellation, motion, legitimate and attacker signals, noise, truth."""

from ..face import lazy_face

# the names other rooms use, by the module that gives them (loaded when first used)
__all__, __getattr__, __dir__ = lazy_face(__name__, {
    "constellation": ("build_constellation",),
    "mavlink_vehicle": ("MavlinkVehicle",),
    "noise": ("gaussian",),
    "run": ("simulate_to_file",),
    "scenario": ("load_scenario",),
    "simulate": ("CHUNK_S", "Simulator", "make_live_simulator"),
    "world": ("run_world",),
})
