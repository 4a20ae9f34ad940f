"""Data compatibility: flight-path reconstruction before eq. (1).

Real data is wrong in its instruments before it is wrong in its model. As
SIDPAC's ``compat`` and Jategaonkar (Flight Vehicle System Identification,
2nd ed., ch. 10) do, the kinematic equations are integrated from the measured
rates and accelerations, and the air-data and attitude channels are compared
with what they should read. The instrument errors are estimated by output
error, pooled over the logs (the same instruments flew them all), each log
with its own initial state:

1. attitude: theta and phi integrated from the gyros give the gyro biases and
   the scale factors and time shifts of the attitude channels;
2. velocity: the body velocity integrated from the accelerometers (a linear
   system once the rates and attitude are known, solved by superposition) gives
   the accelerometer biases, the attitude biases (through gravity), and the bias,
   scale factor and time shift of alpha, beta and airspeed. Sensor positions the
   logs document are taken out first; without one, the distance of the air-data
   head ahead of the CG is estimated too (a boom's vane sees alpha - q x / V).

Standard errors are a delete-one-log jackknife, the logs as clusters: turbulence
is in the air data and not in the kinematics, and it wanders for seconds. Its
replicates are one Gauss-Newton step each; a correction about to be applied on
the kinematics' word alone gets the larger of that and the spread of the whole
estimate made again with each log left out (which errors the logs excite and
which two are confounded move with a log in turbulence). A
parameter the logs do not excite is reported as not identifiable; two the data
cannot tell apart are each estimated with the other held at 0. Corrections larger than a channel's
resolution are applied at 5 standard errors; from 2.5, or when the kinematics
cannot tell two errors apart (an accelerometer bias and an attitude bias), only
if other evidence chooses them: the diagnosis asks the aerodynamic residuals.
These thresholds are :class:`CompatSettings` (the defaults quoted).
The compatibility never reads an instrument profile; it sees the logs only.
"""

from identify.compat.config import CompatSettings
from identify.compat.fit import estimate
from identify.compat.result import (
    D2R,
    EARTH_RATE,
    FT_PER_KT,
    CompatResult,
    Parameter,
    at_cg,
    columns_of,
    documented_positions,
)

__all__ = [
    "D2R",
    "EARTH_RATE",
    "FT_PER_KT",
    "CompatResult",
    "CompatSettings",
    "Parameter",
    "at_cg",
    "columns_of",
    "documented_positions",
    "estimate",
]
