import numpy as np
import pytest

from semperfi.defense.imu_track import find_maneuver, read_imu_csv
from semperfi.flight.maneuver import Leg, ManeuverLimits, plan_trajectory


def test_find_maneuver_in_hover_maneuver_hover(tmp_path):
    legs = (Leg(4.0, 0.0, 0.0, 6.0), Leg(0.0, 4.0, 0.0, 6.0))
    t, n, e, d = plan_trajectory(legs, ManeuverLimits(dt_s=0.1))
    hover = np.arange(0, 30, 0.1)
    tt = np.r_[hover, 30 + t, 30 + t[-1] + 0.1 + hover]
    nn = (np.r_[np.zeros_like(hover), n, np.full_like(hover, n[-1])]
          + 0.05 * np.random.default_rng(1).normal(size=len(tt)))
    ee = np.r_[np.zeros_like(hover), e, np.full_like(hover, e[-1])]
    path = tmp_path / "track.csv"
    with open(path, "w") as f:
        f.write("t_s,north_m,east_m,down_m\n")
        for row in zip(tt, nn, ee, np.zeros_like(tt)):
            f.write(",".join(f"{x:.3f}" for x in row) + "\n")
    track = read_imu_csv(path)
    start, end = find_maneuver(track)
    assert abs(start - 30) < 1.5 and abs(end - (30 + t[-1])) < 1.5


@pytest.mark.parametrize("text", ["", "a,b,c,d\n1,2,3,4\n", "t_s,north_m,east_m,down_m\n0,1,2\n",
                                  "t_s,north_m,east_m,down_m\n0,1,2,x\n1,1,1,1\n",
                                  "t_s,north_m,east_m,down_m\n0,1,2,3\n0,1,2,3\n",
                                  "t_s,north_m,east_m,down_m\n0,nan,2,3\n1,1,2,3\n",
                                  # issue 23, item 3: rows 1e-12 s apart (the maneuver search allocated 7 TiB)
                                  "t_s,north_m,east_m,down_m\n" + "".join(f"{i * 1e-12!r},0,0,0\n" for i in range(50))])
def test_rejects_hostile_csv(tmp_path, text):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError):
        read_imu_csv(path)


def test_a_long_hover_on_a_drifting_ins_is_not_the_maneuver():
    """18 s of hover, the maneuver, 60 s of hover, on an INS 10 mm/s^2 off along north and 6 off along east: its
    velocity error passes 0.8 m/s some 70 s in, a stretch 'moving' longer than the maneuver. The drift, fitted on
    what is still, is taken out."""
    legs = (Leg(8.0, 0.0, 0.0, 6.0), Leg(0.0, 8.0, 0.0, 6.0))
    t, n, e, _ = plan_trajectory(legs, ManeuverLimits(dt_s=0.1))
    before, after = np.arange(0, 18, 0.1), np.arange(0, 60, 0.1)
    tt = np.r_[before, 18 + t, 18 + t[-1] + 0.1 + after]
    nn = np.r_[np.zeros_like(before), n, np.full_like(after, n[-1])] + 0.5 * 0.010 * tt ** 2
    ee = np.r_[np.zeros_like(before), e, np.full_like(after, e[-1])] + 0.5 * 0.006 * tt ** 2
    from semperfi.defense.identifier import ImuTrack
    start, end = find_maneuver(ImuTrack(tt, nn, ee, np.zeros_like(tt)))
    assert abs(start - 18) < 1.5 and abs(end - (18 + t[-1])) < 1.5, (start, end)
