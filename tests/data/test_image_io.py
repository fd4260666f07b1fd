"""Reading images: the 8-bit grey the OpenCV front end tracks is the front ends' float image converted."""

import cv2
import numpy as np
import pytest

from ocalib.data.image_io import grey_image, image_tensor


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("shape", [(17, 23), (17, 23, 3)], ids=["grey", "colour"])
def test_grey_image_is_the_float_image_rounded_to_8_bit_grey(dtype, shape):
    top = np.iinfo(dtype).max
    array = np.random.default_rng(0).integers(0, top + 1, shape, dtype=dtype)
    array.flat[:5] = [0, top, 1, top // 2, top // 2 + 1]
    reference = (image_tensor(array) * 255).round().byte().permute(1, 2, 0).numpy()
    reference = cv2.cvtColor(np.ascontiguousarray(reference), cv2.COLOR_RGB2GRAY)
    grey = grey_image(array)
    assert grey.dtype == np.uint8 and grey.shape == shape[:2]
    np.testing.assert_array_equal(grey, reference)
