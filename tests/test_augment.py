"""Training augmentation: the sensor-like ranges (issue 45, networks that survive the jump to real frames) keep
images, labels and depth aligned and physical, and are repeatable for a seed."""

from __future__ import annotations

import torch

from semmap.train.augment import Augmentation, augment


def _batch(n: int = 2, h: int = 48, w: int = 64):
    g = torch.Generator().manual_seed(0)
    rgb = torch.rand((n, 3, h, w), generator=g)
    labels = (torch.arange(w).view(1, 1, w) // 8).expand(n, h, w).clone().long()  # vertical stripes of classes
    depth = 0.5 + 3.0 * torch.rand((n, 1, h, w), generator=g)
    return rgb, labels, depth


def test_sensor_augmentation_is_repeatable_and_stays_physical() -> None:
    rgb, labels, depth = _batch()
    aug = Augmentation.sensor()
    a = augment(rgb, labels, depth, aug, torch.Generator().manual_seed(7))
    b = augment(rgb, labels, depth, aug, torch.Generator().manual_seed(7))
    assert all(torch.equal(x, y) for x, y in zip(a, b, strict=True))
    out_rgb, out_labels, out_depth = a
    assert out_rgb.shape == rgb.shape and out_labels.shape == labels.shape and out_depth.shape == depth.shape
    assert out_rgb.min() >= 0 and out_rgb.max() <= 1
    assert out_depth.min() >= 0 and set(out_labels.unique().tolist()) <= set(range(8))


def test_photometric_and_depth_changes_leave_the_labels_where_they_are() -> None:
    rgb, labels, depth = _batch()
    aug = Augmentation(flip=False, scale=(1.0, 1.0), brightness=0.4, contrast=0.35, saturation=0.4,
                       white_balance=0.15, gamma=0.35, blur=1.5, noise=0.04, depth_noise=0.004, depth_scale=0.03,
                       depth_holes=0.3)
    out_rgb, out_labels, out_depth = augment(rgb, labels, depth, aug, torch.Generator().manual_seed(3))
    assert torch.equal(out_labels, labels)
    assert not torch.allclose(out_rgb, rgb)
    holes = out_depth == 0
    assert holes.any() and not holes.all()  # blobs of no return, not the whole image
    kept = ~holes
    ratio = out_depth[kept] / depth[kept]
    assert (ratio - 1).abs().median() < 0.05  # a few percent of scale and noise, never more


def test_switched_off_augmentation_passes_the_batch_through() -> None:
    rgb, labels, depth = _batch()
    out = augment(rgb, labels, depth, Augmentation(enabled=False), torch.Generator().manual_seed(0))
    assert out[0] is rgb and out[1] is labels and out[2] is depth


def test_training_can_start_from_a_weight_file_and_fine_tune_it(tmp_path) -> None:
    """--init NET.pt: the same architecture as the file, every tensor copied (a shipped network fine-tuned)."""
    from semmap.errors import ConfigError
    from semmap.labels import INDOOR_LABELS
    from semmap.perception.networks.pretrained import init_plan, load_pretrained
    from semmap.perception.networks.registry import NetworkSpec, build_network, load_weights, save_weights

    spec = NetworkSpec("fcn", num_classes=len(INDOOR_LABELS), width=0.25, depth=18)
    torch.manual_seed(1)
    source = build_network(spec)
    path = save_weights(tmp_path / "fcn.pt", source, spec, INDOOR_LABELS, (64, 48))
    plan = init_plan(str(path))
    assert (plan.model, plan.width, plan.depth) == ("fcn", 0.25, 18)
    torch.manual_seed(2)
    target = build_network(spec)
    summary = load_pretrained(target, str(path))
    stored = load_weights(path).model.state_dict()
    assert not summary.new and all(torch.equal(stored[k], v) for k, v in target.state_dict().items())
    import pytest

    with pytest.raises(ConfigError, match="no such weight file"):
        init_plan(str(tmp_path / "missing.pt"))
