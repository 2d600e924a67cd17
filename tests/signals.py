"""The tests' synthetic C/A signals: semperfi.eval.twin_scene's (scripts/twin-bias-map reads its pairs too); and a
recorder of a guard's events."""

from semperfi.eval.twin_scene import behind_front_end, ca_signal, cancelling_pairs, early_late_balance_chips  # noqa: F401


class Events:
    """What a guard emits, as rows (its events sink)."""
    def __init__(self):
        self.rows = []

    def emit(self, kind, t_s, **fields):
        self.rows.append({"event": kind, "t_s": t_s, **fields})
