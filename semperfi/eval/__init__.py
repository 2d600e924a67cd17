"""Evaluation: scenarios, metrics, the paper's figures, and cross-checks against other receivers."""

from ..face import lazy_face

# the names other rooms use, by the module that gives them (loaded when first used)
__all__, __getattr__, __dir__ = lazy_face(__name__, {
    "autopilot_loop": ("report", "run_autopilot_loop"),
    "demo": ("run_demo",),
    "suite": ("render_suite_report", "run_suite"),
    "sweep": ("load_spec", "ray_available", "read_results", "run_only", "run_sweep"),
    "sweep_report": ("render_report",),
})
