"""The streaming head compiles as one graph (``torch.compile(fullgraph=True)``) and gives the eager result."""

import warnings

import torch
from calib_helpers import lds_rig

from ocalib.calib.drivers.online import OnlineCalibrator


def test_head_compiles_to_one_graph_with_the_eager_result(generator):
    poses, _, _ = lds_rig(generator, frames=24, noise=0.01)
    with torch.inference_mode(), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # made in inference mode, as the buffers each step writes: one graph serves every frame (no recompile)
        eager, compiled = OnlineCalibrator(2, backend="torch"), OnlineCalibrator(2)  # the compiled graph is PyTorch
        step = torch.compile(compiled, fullgraph=True, dynamic=False)  # raises on any graph break
        # raises on a second graph; the C++ kernels unvectorised (a quarter less to compile; the same graph)
        with torch._dynamo.config.patch(error_on_recompile=True), torch._inductor.config.patch({"cpp.simdlen": 0}):
            for t in range(len(poses)):
                a, b = eager(poses[t]), step(poses[t])
    assert not [w for w in caught if "lru_cache" in str(w.message)]  # constants are traced, not cached, when compiling
    torch.testing.assert_close(b.quaternion, a.quaternion, atol=1e-10, rtol=0)
    torch.testing.assert_close(b.translation, a.translation, atol=1e-10, rtol=0)
    for name, buffer in eager.named_buffers():
        torch.testing.assert_close(compiled.get_buffer(name), buffer, atol=1e-10, rtol=0, msg=name)
