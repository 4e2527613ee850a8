"""sie.Odometry: statuses per frame; a refused frame raises and changes nothing."""

from __future__ import annotations

import numpy as np
import pytest

import sie
from test_sie import TRUTH, clouds, pose_error  # noqa: F401 (clouds is a fixture)


def test_frames_get_statuses_and_poses(clouds):  # noqa: F811
    source, target, _ = clouds
    with sie.Odometry() as odometry:
        first = odometry.register_frame(target)
        assert first.status == sie.FrameStatus.FIRST and first.summary is None
        np.testing.assert_array_equal(first.pose, np.eye(4))
        second = odometry.register_frame(source.astype(np.float64))
        assert second.status == sie.FrameStatus.ACCEPTED
        assert second.summary.verdict == sie.Verdict.GOOD
        degrees, metres = pose_error(second.pose, TRUTH)
        assert degrees < 0.2 and metres < 0.004, (degrees, metres)
        np.testing.assert_array_equal(odometry.pose, second.pose)
        again = odometry.register_frame(source.astype(np.float64))
        assert again.status == sie.FrameStatus.REPEATED and again.pose is None
        # Missing returns (NaN, 0 0 0) are skipped by default; a frame of nothing else is refused.
        with pytest.raises(sie.SieError) as refused:
            odometry.register_frame(np.vstack([np.full((5, 3), np.nan), np.zeros((5, 3))]))
        assert refused.value.status == sie.Status.TOO_FEW_POINTS
        np.testing.assert_array_equal(odometry.pose, second.pose)
        odometry.skip_frame()
    with pytest.raises(sie.SieError):
        _ = odometry.pose  # closed
