"""The tests' synthetic C/A signals: semperfi.eval.twin_scene's (scripts/twin-bias-map reads its pairs too)."""

from semperfi.eval.twin_scene import behind_front_end, ca_signal, cancelling_pairs, early_late_balance_chips  # noqa: F401
