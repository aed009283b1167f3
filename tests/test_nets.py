"""`fit --model`: the networks of train.nets.MODELS, and the training step's shape check (the paper's loss bug)."""
from __future__ import annotations

import json

import pytest

torch = pytest.importorskip("torch")

from synthetic_shards import write_shards  # noqa: E402
from train.checkpoint import build_model, load  # noqa: E402
from train.cli import main  # noqa: E402
from train.errors import TrainError  # noqa: E402
from train.inference import predict  # noqa: E402
from train.loop import adam, check_shapes, train_step  # noqa: E402
from train.model import AppdNet, ModelConfig  # noqa: E402
from train.nets import MODELS, PATCH, PatchNet, PlumbLineNet, build  # noqa: E402
from train.plumbline import PlumbLine, feature_matrix  # noqa: E402


class Column(torch.nn.Module):
    """A network that returns (N, 1), as the paper's Keras model did."""

    def __init__(self) -> None:
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.mean(dim=(1, 2, 3))[:, None] * self.w


def test_train_step_refuses_an_n_by_1_prediction_against_an_n_target():
    net = Column()
    batch = {"image": torch.zeros(4, 3, 8, 8, dtype=torch.uint8), "label": torch.rand(4)}
    opt = adam(net.parameters(), 1e-3)
    with pytest.raises(TrainError, match=r"\(4, 1\) differs from the target's \(4,\)"):
        train_step(net, opt, batch, torch.device("cpu"), None)
    # what the check prevents: MSE of (N, 1) against (N,) is over N×N pairs, its optimum the batch mean
    y = torch.tensor([0.0, 1.0, 2.0, 3.0])
    with pytest.warns(UserWarning, match="broadcasting"):
        broadcast = torch.nn.functional.mse_loss(torch.full((4, 1), 1.5), y)
    assert float(broadcast) == pytest.approx(float(((y - 1.5) ** 2).mean()))
    check_shapes(torch.zeros(4), y)  # equal shapes pass


def test_every_model_builds_and_returns_one_value_per_image():
    for arch in (m for m in MODELS if m != "plumbline"):  # the floor: below
        net = build(ModelConfig(348, 128, arch=arch)).eval()
        assert net(torch.rand(2, 3, 128, 348)).shape == (2,)
        dense = build(ModelConfig(348, 128, arch=arch, outputs=6)).eval()
        assert dense(torch.rand(2, 3, 128, 348)).shape == (2, 6)
    assert isinstance(build(ModelConfig(348, 128)), AppdNet)
    with pytest.raises(TrainError, match="model must be one of"):
        build(ModelConfig(348, 128, arch="nope"))


def test_patch_net_sees_every_pixel_through_a_stride_4_stem_and_costs_less_than_the_paper_cnn():
    net = PatchNet(ModelConfig(1392, 512))
    stem = net.features[0]
    assert stem.kernel_size == (PATCH, PATCH) and stem.stride == (PATCH, PATCH)  # non-overlapping, none skipped
    # one pixel's change reaches the output: no stride skips it
    x = torch.rand(1, 3, 512, 1392)
    y = x.clone()
    y[0, :, 257, 695] += 0.5
    net.eval()
    with torch.no_grad():
        assert float((net.features(net.normalize(x)) - net.features(net.normalize(y))).abs().max()) > 0

    def macs(model: torch.nn.Module, w: int, h: int) -> int:
        total = 0

        def hook(m, _, out):
            nonlocal total
            total += out.numel() * m.in_channels * m.kernel_size[0] * m.kernel_size[1] // m.groups

        handles = [m.register_forward_hook(hook) for m in model.modules() if isinstance(m, torch.nn.Conv2d)]
        with torch.no_grad():
            model(torch.rand(1, 3, h, w))
        for handle in handles:
            handle.remove()
        return total

    assert macs(net, 1392, 512) < 0.5 * macs(AppdNet(ModelConfig(348, 128)).eval(), 348, 128)


def fit_tiny(tmp_path, capsys, model: str, batch: int) -> tuple:
    """(run folder, fit's JSON summary) of 3 steps of `model` on 24 synthetic 128x128 samples."""
    shards = write_shards(tmp_path / "shards", n=24, size=(128, 128), per_shard=12)
    run = tmp_path / "run"
    main(["fit", "--shards", str(shards), "--run", str(run), "--steps", "3", "--batch", str(batch), "--workers", "0",
          "--val-split", "none", "--model", model, "--quiet"])
    return run, json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_fit_model_patch_trains_and_its_checkpoint_reloads(tmp_path, capsys):
    run, summary = fit_tiny(tmp_path, capsys, "patch", 4)
    assert summary["step"] == 3
    ckpt = load(run / "last.pt")
    assert ckpt["config"]["model"]["arch"] == "patch" and ckpt["config"]["fit"]["model"] == "patch"
    assert isinstance(build_model(ckpt), PatchNet)


def test_fit_model_plumbline_solves_the_floor_and_evaluate_and_export_use_it(tmp_path, capsys):
    run, summary = fit_tiny(tmp_path, capsys, "plumbline", 8)
    assert summary["step"] == 3 and summary["images"] == 24
    ckpt = load(run / "last.pt")
    assert ckpt["optimizer"] is None
    model = build_model(ckpt)
    assert isinstance(model, PlumbLineNet) and list(model.parameters()) == []
    # the module predicts what train.plumbline's detector predicts from the same 8-bit images
    images = torch.randint(0, 256, (3, 3, 128, 128), dtype=torch.uint8)
    direct = model.floor().predict_features(feature_matrix(i.permute(1, 2, 0).numpy().copy() for i in images))
    assert torch.allclose(model(images.float() / 255), torch.from_numpy(direct).float())
    main(["export", "--ckpt", str(run / "last.pt"), "--json", str(tmp_path / "floor.json")])
    assert PlumbLine.load(tmp_path / "floor.json").alpha == model.floor().alpha
    with pytest.raises(SystemExit):
        main(["export", "--ckpt", str(run / "last.pt"), "--onnx", str(tmp_path / "x.onnx")])
    assert "--json" in capsys.readouterr().err
    with pytest.raises(TrainError, match="not fitted"):
        PlumbLineNet(ModelConfig(128, 128, arch="plumbline"))(torch.rand(1, 3, 128, 128))
    # the closed-form fit keeps the loop's resume rule: a checkpoint at --steps has nothing left to do
    shards = tmp_path / "shards"
    main(["fit", "--shards", str(shards), "--run", str(run), "--steps", "3", "--batch", "8", "--workers", "0",
          "--val-split", "none", "--model", "plumbline", "--quiet", "--resume"])
    assert "already at step 3" in capsys.readouterr().err


def test_predict_reads_every_batch_in_eval_mode_restores_the_mode_and_stops_at_the_limit():
    net = build(ModelConfig(128, 128)).train()  # dropout: train-mode outputs would be random
    images = torch.randint(0, 256, (5, 3, 128, 128), dtype=torch.uint8)
    chunks = [{"image": images[:2], "key": "a"}, {"image": images[2:4], "key": "b"}, {"image": images[4:], "key": "c"}]
    got = list(predict(net, chunks, torch.device("cpu")))
    assert net.training and [b["key"] for b, _ in got] == ["a", "b", "c"]
    with torch.no_grad():
        want = net.eval()(images.float() / 255)
    torch.testing.assert_close(torch.cat([p for _, p in got]), want)  # batches and memory layout: float rounding
    assert [b["key"] for b, _ in predict(net, chunks, torch.device("cpu"), limit=3)] == ["a", "b"]
    assert not net.training  # the mode it had when predict began
