"""The map-level prediction delta_p needs the moments up to h_4."""

import numpy as np
import pytest

from boresight import predict
from boresight.instrument.pairs import PAPER_GAIN


def test_delta_p_needs_the_moments_up_to_h4(small_sky):
    h = np.zeros((4, small_sky.maps.shape[1]), dtype=complex)
    with pytest.raises(ValueError, match="h must have shape"):
        predict.delta_p(small_sky, h, PAPER_GAIN)
