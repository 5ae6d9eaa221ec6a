"""Training: the loss decreases on a tiny synthetic harness clip; checkpoints resume exactly."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from estimate_synth import make_clip
from rvr_addon.errors import InputError
from rvr_addon.estimate.infer import load_estimator
from rvr_addon.estimate.losses import LossWeights
from rvr_addon.estimate.train import Trainer, TrainSettings, sample_loss
from rvr_addon.estimate.unet import EstimatorConfig


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny")
    make_clip(root / "clip0", seed=5, frames=2)
    return root


def settings(run, data, **kw) -> TrainSettings:
    base = dict(run_dir=run, data=[data], iterations=10, lr=1e-3, crop=32, checkpoint_every=5)
    base.update(kw)
    return TrainSettings(**base)


def fixed_loss(trainer: Trainer, n: int = 6) -> float:
    """Mean loss of the same n samples (drawn with their own seed; no gradient)."""
    rng = np.random.default_rng(123)
    samples = [trainer.data.draw(rng) for _ in range(n)]
    with torch.no_grad():
        return float(np.mean([sample_loss(trainer.model, s, LossWeights()).total.item() for s in samples]))


def test_loss_decreases_and_run_folder(tmp_path, tiny_dataset):
    trainer = Trainer(settings(tmp_path / "run", tiny_dataset, iterations=40, checkpoint_every=20))
    before = fixed_loss(trainer)
    trainer.run(progress=False)
    after = fixed_loss(trainer)
    assert after < 0.8 * before, (before, after)
    run = tmp_path / "run"
    for name in ("checkpoint.pt", "loss_log.csv", "loss.png", "run.json", "estimator.pt", "estimator.json"):
        assert (run / name).is_file(), name
    rows = list(csv.DictReader((run / "loss_log.csv").open()))
    assert [int(r["iteration"]) for r in rows] == list(range(1, 41))
    assert {r["kind"] for r in rows} <= {"pair", "aperture", "focal"} and len({r["kind"] for r in rows}) == 3
    header = json.loads((run / "estimator.json").read_text())
    assert header["iterations"] == 40 and header["training"]["training_data"]["harness_frames"] == 2
    assert header["parameters"] == trainer.model.parameter_count()
    loaded = load_estimator(run / "estimator.pt")
    for k, v in trainer.model.state_dict().items():
        assert torch.equal(loaded.net.state_dict()[k], v)
    assert (run / "estimator.pt").stat().st_size < 20e6


@pytest.fixture
def one_thread():
    """torch on one thread: a multi-threaded reduction may sum in another order from run to run
    (1.7e-6 apart after 10 steps was seen), which is not what a resume test is about."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_resume_continues_exactly(tmp_path, tiny_dataset, one_thread):
    straight = Trainer(settings(tmp_path / "a", tiny_dataset, iterations=10))
    straight.run(progress=False)
    first = Trainer(settings(tmp_path / "b", tiny_dataset, iterations=5))
    first.run(progress=False)
    with pytest.raises(InputError, match="--resume"):
        Trainer(settings(tmp_path / "b", tiny_dataset, iterations=10))
    resumed = Trainer(settings(tmp_path / "b", tiny_dataset, iterations=10, resume=True))
    assert resumed.iteration == 5
    resumed.run(progress=False)
    assert resumed.iteration == 10
    for k, v in straight.model.state_dict().items():
        torch.testing.assert_close(resumed.model.state_dict()[k], v, rtol=1e-5, atol=1e-6)
    rows = list(csv.DictReader((tmp_path / "b" / "loss_log.csv").open()))
    assert [int(r["iteration"]) for r in rows] == list(range(1, 11))
    straight_rows = list(csv.DictReader((tmp_path / "a" / "loss_log.csv").open()))
    assert [r["sample"] + r["kind"] for r in rows] == [r["sample"] + r["kind"] for r in straight_rows]


def interrupt_at_draw(trainer: Trainer, n: int, interrupt, monkeypatch) -> None:
    """Call ``interrupt()`` when the trainer draws its n-th sample (step n, batch 1)."""
    real_draw = trainer.data.draw
    calls = {"n": 0}

    def draw(rng):
        calls["n"] += 1
        if calls["n"] == n:
            interrupt()
        return real_draw(rng)

    monkeypatch.setattr(trainer.data, "draw", draw)


def test_ctrl_c_saves_a_checkpoint_and_drops_unsaved_log_rows(tmp_path, tiny_dataset, monkeypatch):
    trainer = Trainer(settings(tmp_path / "run", tiny_dataset, iterations=50, checkpoint_every=100))

    def ctrl_c():
        raise KeyboardInterrupt

    interrupt_at_draw(trainer, 8, ctrl_c, monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        trainer.run(progress=False)
    resumed = Trainer(settings(tmp_path / "run", tiny_dataset, iterations=9, resume=True))
    assert resumed.iteration == 7
    resumed.run(progress=False)
    rows = list(csv.DictReader((tmp_path / "run" / "loss_log.csv").open()))
    assert [int(r["iteration"]) for r in rows] == list(range(1, 10))


def test_bad_settings_and_corrupt_checkpoint(tmp_path, tiny_dataset):
    with pytest.raises(InputError, match="no training data"):
        Trainer(TrainSettings(run_dir=tmp_path / "x"))
    with pytest.raises(InputError, match="does not exist"):
        Trainer(settings(tmp_path / "y", tiny_dataset, resume=True))
    run = tmp_path / "z"
    run.mkdir()
    (run / "checkpoint.pt").write_bytes(b"garbage")
    with pytest.raises(InputError, match="checkpoint.pt"):
        Trainer(settings(run, tiny_dataset, resume=True))


def test_deferred_interrupt_finishes_the_block_first():
    import os
    import signal

    from rvr_addon.estimate.train import deferred_interrupt

    before = signal.getsignal(signal.SIGINT)
    done = []
    with pytest.raises(KeyboardInterrupt):
        with deferred_interrupt():
            os.kill(os.getpid(), signal.SIGINT)
            done.append("update")
    assert done == ["update"]
    assert signal.getsignal(signal.SIGINT) is before


def test_cli_train_and_refusal_to_overwrite(tmp_path, tiny_dataset, capsys):
    from rvr_addon.cli import main

    run = tmp_path / "run"
    args = ["train", "--data", str(tiny_dataset), "-o", str(run), "--crop", "32", "-q"]
    assert main(args + ["--iterations", "3"]) == 0
    assert (run / "estimator.pt").is_file()
    capsys.readouterr()
    assert main(args + ["--iterations", "6"]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main(args + ["--iterations", "6", "--resume"]) == 0
    assert json.loads((run / "estimator.json").read_text())["iterations"] == 6


def test_supervised_terms_are_logged_and_weight_zero_is_the_papers_loss(tmp_path, tiny_dataset):
    sup = Trainer(settings(tmp_path / "sup", tiny_dataset, iterations=4))
    sup.run(progress=False)
    rows = list(csv.DictReader((tmp_path / "sup" / "loss_log.csv").open()))
    for r in rows:
        for k in ("sup", "sup_d", "sup_dgrad", "sup_e", "sup_e0", "d_rms_px", "d_corr", "rss_mb"):
            assert r[k] != "" and np.isfinite(float(r[k])), k
        assert float(r["total"]) > float(r["sup"])  # L_rend is kept in the total
    pure = Trainer(settings(tmp_path / "pure", tiny_dataset, iterations=4, weights=LossWeights(supervised=0.0)))
    sample = pure.data.draw(np.random.default_rng(0))
    with torch.no_grad():
        res = sample_loss(pure.model, sample, LossWeights(supervised=0.0))
    assert "sup" not in res.parts and "d_rms_px" in res.parts  # monitored, not trained on
    assert res.parts["total"] == pytest.approx(2 * res.parts["rend"] + 10 * res.parts["smooth"]
                                               if sample.adjusted is None else
                                               res.parts["rend"] + res.parts["adjust"] + 10 * res.parts["smooth"],
                                               rel=1e-5)
    pure.run(progress=False)
    rows = list(csv.DictReader((tmp_path / "pure" / "loss_log.csv").open()))
    assert all(r["sup"] == "" and r["d_rms_px"] != "" for r in rows)
    assert json.loads((tmp_path / "pure" / "run.json").read_text())["loss_weights"]["supervised"] == 0.0


def test_supervision_pulls_disparity_toward_the_truth(tmp_path, tiny_dataset):
    """A few steps with only the disparity term (rendering loss weights ~0) shrink the D error."""
    w = LossWeights(pix=0.0, ssim=0.0, grad=0.0, smooth=0.0, supervised=1.0, sup_exponent=0.0,
                    sup_exponent_zero=0.0)
    trainer = Trainer(settings(tmp_path / "run", tiny_dataset, iterations=10, weights=w, lr=2e-3))
    rng = np.random.default_rng(7)
    samples = [trainer.data.draw(rng) for _ in range(4)]

    def d_rms() -> float:
        with torch.no_grad():
            return float(np.mean([sample_loss(trainer.model, s, w).parts["d_rms_px"] for s in samples]))

    before = d_rms()
    trainer.run(progress=False)
    after = d_rms()
    assert after < 0.7 * before, (before, after)


def test_cli_supervised_options(tmp_path, tiny_dataset):
    from rvr_addon.cli import main

    run = tmp_path / "run"
    assert main(["train", "--data", str(tiny_dataset), "-o", str(run), "--crop", "32", "-q", "--iterations", "2",
                 "--supervised-weight", "0.25", "--w-exponent", "2", "--disparity-invariant", "--whole-frame", "1",
                 "--threads", "1"]) == 0
    rec = json.loads((run / "run.json").read_text())
    assert rec["loss_weights"]["supervised"] == 0.25 and rec["loss_weights"]["sup_exponent"] == 2.0
    assert rec["loss_weights"]["disparity_invariant"] is True and rec["whole_frame"] == 1.0
    assert main(["train", "--data", str(tiny_dataset), "-o", str(tmp_path / "x"), "-q",
                 "--supervised-weight", "-1"]) == 2


def test_init_from_weights_grows_the_row_prior_and_keeps_the_output(tmp_path, tiny_dataset, capsys):
    from rvr_addon.cli import main

    first = tmp_path / "first"
    assert main(["train", "--data", str(tiny_dataset), "-o", str(first), "--crop", "32", "-q",
                 "--iterations", "3"]) == 0
    base = load_estimator(first / "estimator.pt").net
    assert not base.config.row_prior
    grown = Trainer(settings(tmp_path / "grown", tiny_dataset, init_from=first / "estimator.pt",
                             model=EstimatorConfig(row_prior=True)))
    assert grown.model.config.row_prior and grown.iteration == 0
    x = torch.rand(1, 3, 40, 72)
    with torch.no_grad():  # the added row channel starts at zero weight: the same prediction
        assert torch.equal(grown.model(x).disparity_rel, base(x).disparity_rel)
    record = json.loads((tmp_path / "grown" / "run.json").read_text())["init_from"]
    assert record["row_prior_added"] and record["iterations"] == 3
    grown.run(progress=False)
    assert grown.model.grid_head.weight[:, -1].abs().sum() > 0  # the prior gets a gradient
    # resumed, the run still says where it started; --init-from with --resume is refused
    again = Trainer(settings(tmp_path / "grown", tiny_dataset, iterations=12, resume=True))
    assert again.init_record == record
    again.close()
    capsys.readouterr()
    assert main(["train", "--data", str(tiny_dataset), "-o", str(tmp_path / "grown"), "--crop", "32", "-q",
                 "--resume", "--init-from", str(first / "estimator.pt")]) == 2
    assert "--init-from" in capsys.readouterr().err


def test_grow_state_dict_refuses_other_changes():
    from rvr_addon.estimate.unet import EstimatorNet, grow_state_dict

    old = EstimatorConfig(widths=(8, 16, 24))
    state = EstimatorNet(old).state_dict()
    assert grow_state_dict(state, old, old).keys() == state.keys()
    with pytest.raises(ValueError, match="row_prior"):
        grow_state_dict(state, old, EstimatorConfig(widths=(8, 16, 32), row_prior=True))
    with pytest.raises(ValueError, match="row_prior"):
        grow_state_dict(state, EstimatorConfig(widths=(8, 16, 24), row_prior=True), old)


def test_resume_at_its_count_exports_the_weights(tmp_path, tiny_dataset):
    """A run stopped by a signal after its last checkpoint (no weights file) is exported by
    resuming it with the iteration count it already has."""
    from rvr_addon.cli import main

    run = tmp_path / "run"
    args = ["train", "--data", str(tiny_dataset), "-o", str(run), "--crop", "32", "-q", "--iterations", "4"]
    assert main(args + ["--checkpoint-every", "2"]) == 0
    (run / "estimator.pt").unlink()
    assert main(args + ["--resume"]) == 0
    assert json.loads((run / "estimator.json").read_text())["iterations"] == 4
    assert load_estimator(run / "estimator.pt").header["iterations"] == 4


def test_sigterm_saves_a_checkpoint_like_ctrl_c(tmp_path, tiny_dataset, monkeypatch):
    """A scheduler's SIGTERM (or `kill`) mid-run: the step being drawn is dropped (an update in
    progress would complete first), the checkpoint is saved, and --resume continues from it."""
    import os
    import signal

    trainer = Trainer(settings(tmp_path / "run", tiny_dataset, iterations=50, checkpoint_every=100))
    # arrives while step 6 draws its sample
    interrupt_at_draw(trainer, 6, lambda: os.kill(os.getpid(), signal.SIGTERM), monkeypatch)
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt):
        trainer.run(progress=False)
    assert signal.getsignal(signal.SIGTERM) is before
    resumed = Trainer(settings(tmp_path / "run", tiny_dataset, iterations=50, resume=True))
    assert resumed.iteration == 5
