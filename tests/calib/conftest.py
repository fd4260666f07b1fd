import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread():
    """The calibration's tensors are tiny: intra-op threads only add hand-over cost (10x slower on a loaded
    2-core machine)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
