"""``model.compile``: the training step is captured as one graph and computes the eager step's loss and gradients.

Inductor's C++ code generation takes minutes on two cores, so the test compiles with the ``aot_eager`` backend: the
same dynamo capture and AOTAutograd forward and backward graphs that inductor would generate code for, run by
eager kernels. ``fullgraph=True`` turns a graph break (a slower step, part of it left eager) into a failure.
"""

import pytest
import torch
from ocalib.train.module import EgoMotionModule

H, W = 32, 96


def snippets(batch: int = 2) -> dict:
    g = torch.Generator().manual_seed(0)
    image = torch.rand(batch, 3, 3, H, W, generator=g)
    K = torch.tensor([[55.0, 0, 47.5], [0, 60.0, 15.5], [0, 0, 1]]).expand(batch, 3, 3).clone()
    return {"image": image, "K": K}


def test_compiled_training_step_is_one_graph_with_the_eager_loss_and_gradients(monkeypatch):
    compile_, compiled = torch.compile, []

    def compile_for_test(fn, **kwargs):
        compiled.append(fn)
        return compile_(fn, backend="aot_eager", fullgraph=True)

    monkeypatch.setattr(torch, "compile", compile_for_test)
    torch.manual_seed(0)
    module = EgoMotionModule(
        height=H, width=W, geometry=0.0, scales=1, automask=False, align=(2, 2), distill=0.1, compile=True
    )
    module.log = lambda *a, **k: None  # outside a Trainer
    batch, state = snippets(), {k: v.clone() for k, v in module.state_dict().items()}

    eager, _, _ = module.step(batch)
    eager.total.backward()
    eager_grads = [None if p.grad is None else p.grad.clone() for p in module.parameters()]
    module.load_state_dict(state)  # the batch-norm statistics the eager step moved
    module.zero_grad(set_to_none=True)

    loss = module.training_step(batch, 0)
    loss.backward()
    assert compiled == [module.step]
    torch.testing.assert_close(loss, eager.total, rtol=1e-5, atol=1e-6)
    for p, expected in zip(module.parameters(), eager_grads):
        assert (p.grad is None) == (expected is None)
        if expected is not None:
            torch.testing.assert_close(p.grad, expected, rtol=1e-3, atol=1e-6)
    assert sum(p.grad is not None for p in module.parameters()) > 50  # both networks learn


def test_without_a_cpp_compiler_the_step_stays_eager_with_a_warning(monkeypatch):
    monkeypatch.delenv("CXX", raising=False)
    monkeypatch.setattr("shutil.which", lambda name: None)
    module = EgoMotionModule(height=H, width=W, compile=True)
    module.log = lambda *a, **k: None  # outside a Trainer
    with pytest.warns(UserWarning, match="C\\+\\+ compiler"):
        loss = module.training_step(snippets(), 0)
    assert module._train_step == module.step and torch.isfinite(loss)
