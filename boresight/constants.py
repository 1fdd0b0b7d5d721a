"""Physical and angular constants used across boresight (angles in radians inside the code)."""

import numpy as np

DEG = np.pi / 180.0  #: one degree in radians
ARCMIN = np.pi / 10800.0  #: one arcminute in radians
N_MAX = 4  #: the highest spin moment h_n that the statistics keep and the predictions use
