"""SDCNet's building blocks, variants, losses, checkpoints and a few real training steps."""

import numpy as np
import pytest
import torch

from sdcnet.camera import PAPER_CAMERA
from sdcnet.dataset_format import SampleStore, write_sample
from sdcnet.pipeline import Region
from sdcnet.training.checkpoint import load_checkpoint, save_checkpoint, transplant_weights
from sdcnet.training.dataset import TileDataset, cut_returns, holding_target
from sdcnet.training.losses import (
    depth_gradient_loss,
    foreground_depth_loss,
    laplace_nll,
    segmentation_loss,
    soft_iou_loss,
)
from sdcnet.training.model.blocks import space_to_depth
from sdcnet.training.model.cca import CrossChannelAttention
from sdcnet.training.model.mask_refiner import MaskRefiner
from sdcnet.training.model.prefill import NearestReturnFill, near_wins_downsample
from sdcnet.training.model.sdcnet import (
    VARIANTS,
    ModelConfig,
    SDCNet,
    build_model,
    local_depth_spread,
)
from tests.support.frames import write_dataset

FOCAL = torch.full((1, 1, 1, 1), 7939.2)


def lidar_like(batch: int, height: int, width: int, depth: float = 120.0) -> torch.Tensor:
    sparse = torch.zeros(batch, 1, height, width)
    sparse[:, :, 5::18, 3::12] = depth
    return sparse


def focal(batch: int) -> torch.Tensor:
    return FOCAL.expand(batch, 1, 1, 1)


def test_fsnet_has_about_five_thousand_parameters():
    model = SDCNet()
    n = sum(p.numel() for p in model.fsnet.parameters())
    assert 4000 <= n <= 6500, n
    assert sum(1 for m in model.fsnet.modules() if isinstance(m, torch.nn.Conv2d)) == 8


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_every_variant_accepts_odd_sizes_and_batches(variant):
    torch.manual_seed(0)
    model = SDCNet(VARIANTS[variant]).eval()
    gray, sparse = torch.rand(2, 1, 77, 131), lidar_like(2, 77, 131)
    with torch.no_grad():
        depth, prob, sigma = model(gray, sparse, focal(2))
    assert depth.shape == prob.shape == sigma.shape == (2, 1, 77, 131)
    assert torch.isfinite(depth).all() and ((prob >= 0) & (prob <= 1)).all()
    assert torch.isfinite(sigma).all() and (sigma > 0).all()
    if model.fsnet is not None:  # stage 1 trains exactly the mask the full model outputs
        with torch.no_grad():
            torch.testing.assert_close(model.segment(gray, sparse, focal(2)), prob)


@pytest.mark.parametrize("inputs", ["gray", "sparse", "both"])
def test_fsnet_input_choices_of_table_4(inputs):
    model = SDCNet(ModelConfig(fsnet_inputs=inputs)).eval()
    with torch.no_grad():
        _, prob, _ = model(torch.rand(1, 1, 64, 64), lidar_like(1, 64, 64), FOCAL)
    assert prob.shape == (1, 1, 64, 64)


def test_cca_weights_and_attention_do_not_depend_on_input_size():
    cca = CrossChannelAttention(channels=16, grid=4, heads=4)
    shapes = {k: v.shape for k, v in cca.state_dict().items()}
    for size in ((16, 16), (32, 48), (64, 24)):
        f_s, f_g = torch.rand(2, 16, *size), torch.rand(2, 16, *size)
        assert cca.attention(f_s, f_g).shape == (2, 4, 16, 16)
        assert cca(f_s, f_g).shape == (2, 16, *size)
    assert {k: v.shape for k, v in cca.state_dict().items()} == shapes
    assert cca.d_k == 48  # 3 features x 16 regions


def test_prefill_fills_between_returns_near_wins_and_says_how_far():
    sparse = lidar_like(1, 128, 128, depth=100.0)
    sparse[0, 0, 5, 3] = 0
    sparse[0, 0, 41, 39] = 60.0  # a nearer surface in one block
    lr = near_wins_downsample(sparse, 4)
    assert lr[0, 0, 10, 9] == 60.0
    filled, level = NearestReturnFill()(lr)
    inner = filled[0, 0, 4:28, 4:28]
    assert (inner > 0).all(), "returns ~3 x 4.5 px apart at the working resolution are bridged"
    assert inner.min() >= 59.9 and inner.max() <= 100.0
    assert level[0, 0, 10, 9] == 0 and level[0, 0, 11, 9] == pytest.approx(0.2)
    lone = torch.zeros(1, 1, 64, 64)
    lone[0, 0, 32, 32] = 50.0  # one return: reached by ever wider squares, up to 16 cells away
    filled, level = NearestReturnFill()(lone)
    assert (filled[0, 0, 16:49, 16:49] == 50.0).all() and filled[0, 0, 0, 0] == 0
    assert level[0, 0, 32, 40] == pytest.approx(0.8) and level[0, 0, 0, 0] == 1.0


def test_foreground_loss_ignores_pixels_outside_the_predicted_foreground():
    gt = torch.full((1, 1, 8, 8), 100.0)
    prob = torch.zeros(1, 1, 8, 8)
    prob[..., :4] = 0.9
    depth = torch.full((1, 1, 8, 8), 101.0, requires_grad=True)
    loss = foreground_depth_loss(depth, prob, gt)
    loss.backward()
    assert loss.item() == pytest.approx(1.0)
    assert (depth.grad[..., 4:] == 0).all() and (depth.grad[..., :4] != 0).all()
    wild = depth.detach().clone()
    wild[..., 4:] = -5000.0
    assert foreground_depth_loss(wild, prob, gt).item() == pytest.approx(1.0)


def test_segmentation_loss_is_bce():
    gt = torch.tensor([[[[0.0, 50.0]]]])
    prob = torch.tensor([[[[0.25, 0.5]]]])
    expected = -(np.log(0.75) + np.log(0.5)) / 2
    assert segmentation_loss(prob, gt).item() == pytest.approx(expected, rel=1e-5)


def test_checkpoint_round_trip(tmp_path):
    torch.manual_seed(1)
    model = SDCNet(VARIANTS["fsnet+cca"]).eval()
    save_checkpoint(tmp_path / "m.pt", model, note="x")
    loaded, state = load_checkpoint(tmp_path / "m.pt")
    assert loaded.config == model.config and state["note"] == "x"
    gray, sparse = torch.rand(1, 1, 64, 64), lidar_like(1, 64, 64)
    with torch.no_grad():
        for a, b in zip(model(gray, sparse, FOCAL), loaded(gray, sparse, FOCAL), strict=True):
            torch.testing.assert_close(a, b)
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="cannot read checkpoint"):
        load_checkpoint(tmp_path / "bad.pt")


def test_a_few_optimisation_steps_reduce_both_losses(tiny_dataset):
    torch.manual_seed(0)
    store = SampleStore(tiny_dataset)
    data = TileDataset(store, store.records[:2], tile=128, stride=64)
    names = ("gray", "sparse", "depth", "focal_px")
    batch = {k: torch.stack([data[i][k] for i in range(2)]) for k in names}
    assert (batch["depth"] > 0).any()
    inputs = (batch["gray"], batch["sparse"], batch["focal_px"])
    model = SDCNet()
    seg = torch.optim.Adam(model.segmentation_parameters(), lr=1e-2)
    losses = []
    for _ in range(20):
        prob = model.segment(*inputs)
        loss = segmentation_loss(prob, batch["depth"])
        seg.zero_grad()
        loss.backward()
        seg.step()
        losses.append(loss.item())
    assert losses[-1] < 0.75 * losses[0]
    seg_ids = set(map(id, model.segmentation_parameters()))
    rest = [p for p in model.parameters() if id(p) not in seg_ids]
    opt = torch.optim.Adam(rest, lr=3e-3)
    model.fsnet.eval()
    depth_losses = []
    unit = model.residual_unit(batch["sparse"], batch["focal_px"])
    for _ in range(12):
        depth, prob, _ = model(*inputs)
        loss = foreground_depth_loss(depth, prob.detach(), batch["depth"], unit)
        opt.zero_grad()
        loss.backward()
        opt.step()
        depth_losses.append(loss.item())
    assert depth_losses[-1] < 0.8 * depth_losses[0]


def test_gradient_loss_sees_a_ripple_the_l1_loss_forgives():
    gt = torch.full((1, 1, 4, 4), 100.0)
    ripple = gt + torch.tensor([0.01, -0.01, 0.01, -0.01]).reshape(1, 1, 4, 1)  # rows alternate
    prob = torch.ones(1, 1, 4, 4)
    assert foreground_depth_loss(ripple, prob, gt).item() == pytest.approx(0.01, rel=1e-3)
    # 12 vertical pairs step by 0.02 m, 12 horizontal pairs do not step: mean 0.01 m per pixel
    assert depth_gradient_loss(ripple, prob, gt).item() == pytest.approx(0.01, rel=1e-3)
    assert depth_gradient_loss(gt + 0.5, prob, gt).item() == pytest.approx(0.0, abs=1e-5)
    prob[..., :2, :] = 0  # the last two rows: 4 vertical pairs (0.02 m off), 6 horizontal ones
    assert depth_gradient_loss(ripple, prob, gt).item() == pytest.approx(4 * 0.02 / 10, rel=1e-3)


def test_soft_iou_loss_is_one_minus_the_iou_of_a_hard_mask():
    gt = torch.zeros(1, 1, 4, 4)
    gt[..., :2, :] = 50.0  # 8 pixels of foreground
    prob = torch.zeros(1, 1, 4, 4)
    prob[..., 1:3, :] = 1.0  # 8 pixels predicted, 4 right: IOU 4 / 12
    assert soft_iou_loss(prob, gt).item() == pytest.approx(1 - 4 / 12)
    assert soft_iou_loss((gt > 0).float(), gt).item() == pytest.approx(0.0)


def test_the_soft_iou_per_tile_weighs_a_small_spacecraft_like_a_large_one():
    gt = torch.zeros(3, 1, 8, 8)
    gt[0, :, :6, :] = 50.0  # 48 pixels, all found
    gt[1, :, :1, :2] = 50.0  # 2 pixels, one found: IOU 1 / 2
    prob = (gt > 0).float()
    prob[1, :, 0, 1] = 0.0  # tile 2 holds no spacecraft: left out of the mean
    assert soft_iou_loss(prob, gt, per_tile=True).item() == pytest.approx((0 + 0.5) / 2)
    assert soft_iou_loss(prob, gt).item() == pytest.approx(1 - 49 / 50)


@pytest.mark.parametrize("block", [2, 4])
def test_space_to_depth_is_pixel_unshuffle_exactly(block):
    x = torch.randn(3, 1, 16, 24) * 100
    assert torch.equal(space_to_depth(x, block), torch.nn.functional.pixel_unshuffle(x, block))
    with pytest.raises(ValueError, match="one channel"):
        space_to_depth(torch.zeros(1, 2, 8, 8), block)


@pytest.mark.parametrize("block", [1, 2, 4])
def test_the_refiner_over_blocks_equals_its_convolutions_at_full_resolution(block):
    """The reference: the two 3 x 3 convolutions run at full resolution with zero padding, as
    the checkpoint's weights define them; the refiner computes them over space-to-depth blocks."""
    torch.manual_seed(block)
    refiner = MaskRefiner(block=block, hidden=5)
    for p in refiner.parameters():
        torch.nn.init.normal_(p)  # the correction starts at zero: give it weights
    gray, logit = torch.rand(2, 1, 24, 32), torch.randn(2, 1, 24, 32)
    conv1, conv2 = refiner.features[0], refiner.correction
    hidden = torch.relu(
        torch.nn.functional.conv2d(torch.cat([gray, logit], 1), conv1.weight, conv1.bias, padding=1)
    )
    expected = logit + torch.nn.functional.conv2d(hidden, conv2.weight, conv2.bias, padding=1)
    unshuffle = torch.nn.functional.pixel_unshuffle
    with torch.no_grad():
        got = refiner(unshuffle(gray, block), unshuffle(logit, block))
    torch.testing.assert_close(torch.nn.functional.pixel_shuffle(got, block), expected)


def test_an_untrained_refiner_leaves_fsnets_mask_as_it_was():
    torch.manual_seed(0)
    plain = build_model("sdcnet", mask_refiner=False).eval()
    refined = build_model("sdcnet").eval()
    refined.load_state_dict(plain.state_dict(), strict=False)
    assert set(refined.state_dict()) - set(plain.state_dict()) == {
        f"refiner.{k}" for k in refined.refiner.state_dict()
    }
    gray, sparse = torch.rand(1, 1, 128, 128), lidar_like(1, 128, 128)
    with torch.no_grad():
        torch.testing.assert_close(
            plain.segment(gray, sparse, FOCAL), refined.segment(gray, sparse, FOCAL)
        )
    trainable = {id(p) for p in refined.segmentation_parameters()}
    assert all(id(p) in trainable for p in refined.refiner.parameters())


def test_a_widened_fsnet_starts_as_the_narrow_one_and_its_new_channels_learn():
    """``--warm-start`` from a model with a narrower FSNet (``fsnet_growth``): the wide network
    first computes the same mask, and one step moves the weights of its new channels."""
    torch.manual_seed(0)
    narrow = build_model("sdcnet")
    for module in narrow.fsnet.modules():  # trained-like BN statistics and a live head
        if isinstance(module, torch.nn.BatchNorm2d):
            torch.nn.init.uniform_(module.running_mean, -0.5, 0.5)
            torch.nn.init.uniform_(module.running_var, 0.5, 2.0)
            torch.nn.init.uniform_(module.bias, -0.2, 0.2)
    torch.nn.init.normal_(narrow.fsnet.head.weight, std=0.5)
    wide = build_model("sdcnet", fsnet_growth=2)
    report = transplant_weights(wide, narrow.state_dict())
    assert not report["left"] and "fsnet.dec2.0.weight" in report["partial"]
    assert sum(p.numel() for p in wide.fsnet.parameters()) > 3.5 * sum(
        p.numel() for p in narrow.fsnet.parameters()
    )
    gray, sparse = torch.rand(1, 1, 128, 128), lidar_like(1, 128, 128)
    narrow.eval(), wide.eval()
    with torch.no_grad():
        torch.testing.assert_close(
            narrow.segment(gray, sparse, FOCAL), wide.segment(gray, sparse, FOCAL)
        )
    wide.train()
    old_rows = narrow.fsnet.dec1[0].out_channels
    new_inputs = wide.fsnet.head.weight[:, old_rows:].detach().clone()
    assert (new_inputs == 0).all()
    optimiser = torch.optim.SGD(wide.segmentation_parameters(), lr=0.1)
    wide.segment(gray, sparse, FOCAL).mean().backward()
    optimiser.step()
    assert (wide.fsnet.head.weight[:, old_rows:] != 0).any()


def test_fsnets_context_branch_starts_at_nothing_and_sees_past_the_narrow_reach():
    """``fsnet_context``: warm-started from a model without it, the same mask at first (its
    last convolution starts at zero); trained, a change 88 input pixels away moves a pixel's
    logit, which the narrow network's receptive field does not reach."""
    torch.manual_seed(0)
    plain = build_model("sdcnet", fsnet_growth=2).eval()
    wide_view = build_model("sdcnet", fsnet_growth=2, fsnet_context=True).eval()
    report = transplant_weights(wide_view, plain.state_dict())
    assert all(n.startswith("fsnet.context.") for n in report["left"]) and report["left"]
    gray, sparse = torch.rand(1, 1, 256, 256), lidar_like(1, 256, 256)
    with torch.no_grad():
        torch.testing.assert_close(
            plain.segment(gray, sparse, FOCAL), wide_view.segment(gray, sparse, FOCAL)
        )
        for layer in wide_view.fsnet.context.modules():  # a trained-like branch
            if isinstance(layer, torch.nn.Conv2d):
                torch.nn.init.normal_(layer.weight, std=0.5)

    def moved(model: SDCNet) -> float:
        x = model_input(model, gray, sparse)  # FSNet's grid: half the input's
        far = x.clone()
        far[..., 64:84, 64:84] += 1.0  # 44+ FSNet pixels from the one watched, (20, 20)
        with torch.no_grad():
            return float((model.fsnet(x) - model.fsnet(far))[..., 20, 20].abs().max())

    assert moved(plain) == 0.0
    assert moved(wide_view) > 1e-4


def model_input(model: SDCNet, gray: torch.Tensor, sparse: torch.Tensor) -> torch.Tensor:
    """FSNet's input tensor for ``gray`` and ``sparse`` (what ``SDCNet._segment`` builds)."""
    captured = []
    hook = model.fsnet.register_forward_pre_hook(lambda _, args: captured.append(args[0]))
    try:
        with torch.no_grad():
            model.segment(gray, sparse, FOCAL)
    finally:
        hook.remove()
    return captured[0]


def _trained_like(seed: int = 0) -> SDCNet:
    """SDCNet with random weights everywhere, its residual head included (a fresh one starts
    at zero and would hide what the network does with its inputs)."""
    torch.manual_seed(seed)
    model = SDCNet().eval()
    torch.nn.init.normal_(model.fdcnet.head.weight, std=0.05)
    torch.nn.init.normal_(model.fsnet.head.weight, std=0.5)
    return model


def test_a_scene_k_times_larger_and_farther_gives_k_times_the_depth_and_the_same_mask():
    """The same image and returns at the same pixels, every length times k: the network must
    not see the scale in metres (a 3 m docking frame and a 250 m one look alike to it)."""
    model = _trained_like()
    gray = torch.rand(1, 1, 128, 160)
    sparse = lidar_like(1, 128, 160, depth=30.0)
    sparse[sparse > 0] += torch.rand(int((sparse > 0).sum())) * 2.0  # a relief of 2 m
    with torch.no_grad():
        depth, prob, sigma = model(gray, sparse, FOCAL)
        far_depth, far_prob, far_sigma = model(gray, 8.0 * sparse, FOCAL)
    torch.testing.assert_close(far_depth, 8.0 * depth, rtol=1e-4, atol=1e-3)
    torch.testing.assert_close(far_prob, prob, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(far_sigma, 8.0 * sigma, rtol=1e-4, atol=1e-5)


def test_the_exposure_of_the_image_does_not_change_the_answer():
    """An image four times darker (under-exposed, or 12 bits in 16) is scaled back by the mean
    gray at the returns: the same answer."""
    model = _trained_like(1)
    gray = torch.rand(1, 1, 128, 128) * 0.5
    sparse = lidar_like(1, 128, 128)
    with torch.no_grad():
        bright = model(gray, sparse, FOCAL)
        dark = model(gray / 4, sparse, FOCAL)
    for a, b in zip(bright, dark, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-4)


def test_the_laplace_nll_is_its_hand_computed_value_and_never_moves_the_depth():
    gt = torch.tensor([[[[100.0, 100.0, 0.0]]]])
    depth = torch.tensor([[[[100.3, 99.0, 50.0]]]], requires_grad=True)
    scale = torch.tensor([[[[0.5, 2.0, 1.0]]]], requires_grad=True)
    prob = torch.ones(1, 1, 1, 3)
    unit = 0.25  # metres: log(b / unit)
    loss = laplace_nll(depth.detach(), scale, prob, gt, unit)
    expected = ((0.3 / 0.5 + np.log(0.5 / 0.25)) + (1.0 / 2.0 + np.log(2.0 / 0.25))) / 2
    assert loss.item() == pytest.approx(expected, rel=1e-5)  # the sky pixel is left out
    loss.backward()
    assert depth.grad is None and scale.grad[0, 0, 0, 2] == 0
    # its minimum over the scale is the absolute error: d/db (e / b + log b) = 0 at b = e
    b = torch.tensor([[[[0.3, 1.0, 1.0]]]], requires_grad=True)
    laplace_nll(depth.detach(), b, prob, gt).backward()
    torch.testing.assert_close(b.grad[..., :2], torch.zeros(1, 1, 1, 2), atol=1e-4, rtol=0)


def test_the_depth_spread_is_the_step_at_a_depth_edge_and_zero_on_a_flat_panel():
    """A panel at 10 m in front of one at 13 m: the spread is 3 m within two pixels of the
    edge, 0 farther away and off the foreground."""
    depth = torch.full((1, 1, 12, 12), 13.0)
    depth[..., :, :6] = 10.0
    foreground = torch.ones_like(depth, dtype=torch.bool)
    foreground[..., :, 11] = False
    spread = local_depth_spread(depth, foreground)
    assert torch.allclose(spread[..., :, 4:8], torch.tensor(3.0))
    assert not spread[..., :, :4].any() and not spread[..., :, 8:11].any()
    assert not spread[..., :, 11].any()


def test_the_depth_edge_term_joins_sigma_at_inference_only():
    """Training fits the scale head's own Laplace scale; the calibrated edge term is added in
    quadrature when the model answers."""
    torch.manual_seed(0)
    plain = SDCNet(ModelConfig()).eval()
    edged = SDCNet(ModelConfig(sigma_edge_weight=0.5))
    edged.load_state_dict(plain.state_dict())
    gray, sparse = torch.rand(1, 1, 64, 64), torch.zeros(1, 1, 64, 64)
    sparse[..., ::9, ::6] = 80.0
    sparse[..., 30:, ::6] = torch.where(sparse[..., 30:, ::6] > 0, 90.0, 0.0)
    focal = torch.full((1, 1, 1, 1), 2000.0)
    with torch.no_grad():  # both in training mode alike (batch statistics), then answering
        _, _, trained_plain = plain.train()(gray, sparse, focal)
        _, _, trained = edged.train()(gray, sparse, focal)
        depth, prob, sigma = plain.eval()(gray, sparse, focal)
        _, _, answered = edged.eval()(gray, sparse, focal)
    torch.testing.assert_close(trained, trained_plain)
    spread = 0.5 * local_depth_spread(depth, prob > 0.5)
    assert spread.any()
    torch.testing.assert_close(answered, torch.sqrt(sigma**2 + spread**2))


def test_holding_target_joins_the_truth_box_to_the_region():
    depth = np.zeros((100, 120), np.float32)
    depth[30:40, 10:90] = 50.0
    grown = holding_target(Region(20, 60, 40, 70), depth)
    assert (grown.y0, grown.y1, grown.x0, grown.x1) == (20, 60, 10, 90)
    assert holding_target(Region(1, 2, 3, 4), np.zeros_like(depth)) == Region(1, 2, 3, 4)


def test_whole_target_items_hold_the_parts_no_return_reached(tmp_path):
    """Returns on the left half of the spacecraft only (the right half dark, its returns
    lost): the pipeline's crop cuts the right wing away; a whole-target item keeps all of it."""
    root = write_dataset(tmp_path / "data", {"train": 1}, size=256)
    store = SampleStore(root)
    sample = store.load(store.records[0])
    K = PAPER_CAMERA.intrinsics().scaled(256, 256)
    sample.sparse[:, 128:] = 0
    sample.gray[:, 128:] = np.minimum(sample.gray[:, 128:], 30)
    sample.meta["intrinsics"] = K.as_dict()
    write_sample(root / store.records[0]["file"], sample)
    covered = {}
    for share in (0.0, 1.0):
        item = TileDataset(store, store.records, tile=None, stride=64, whole_target_share=share)[0]
        scale = float(item["focal_px"]) / K.fx  # working pixels per frame pixel
        covered[share] = float((item["depth"] > 0).sum()) / scale**2 / sample.mask.sum()
    assert covered[1.0] == pytest.approx(1.0, abs=0.05)
    assert covered[0.0] < 0.85
    with pytest.raises(ValueError, match="whole_target_share"):
        TileDataset(store, store.records, stride=64, whole_target_share=1.5)


def test_a_training_item_reads_a_12_bit_frame_in_the_low_bits_as_the_service_does(tmp_path):
    """The same frame from a 12-bit camera, its values in a 16-bit image's top bits and in
    its low bits: one training item, as the pipeline answers both alike (``in_top_bits``)."""
    root = write_dataset(tmp_path / "data", {"train": 2}, size=256)
    store = SampleStore(root)
    top, low = (store.load(r) for r in store.records)
    top.gray = top.gray.astype(np.uint16) << 8  # 12-bit values in the top bits
    low.gray, low.sparse, low.depth = top.gray >> 4, top.sparse, top.depth
    for record, sample in zip(store.records, (top, low), strict=True):
        sample.meta["intrinsics"] = PAPER_CAMERA.intrinsics().scaled(256, 256).as_dict()
        write_sample(root / record["file"], sample)
    items = TileDataset(store, store.records, tile=None, stride=64)
    for name in ("gray", "sparse", "depth", "focal_px"):
        assert torch.equal(items[0][name], items[1][name])


def test_a_field_cut_drops_the_returns_past_a_straight_line_and_keeps_the_truth(tmp_path):
    sparse = np.zeros((64, 80), np.float32)
    sparse[8:56:4, 10:70:4] = 50.0  # a grid of returns over rows 8-52, columns 10-66
    for seed in range(12):
        cut = cut_returns(sparse, np.random.default_rng(seed))
        assert set(np.unique(cut)) <= {0.0, 50.0} and 0 < (cut > 0).sum() < (sparse > 0).sum()
        kept_rows, kept_cols = np.nonzero(cut > 0)
        lost_rows, lost_cols = np.nonzero((sparse > 0) & (cut == 0))
        # one straight line, a row or a column, between what is kept and what is lost
        by_row = kept_rows.max() < lost_rows.min() or kept_rows.min() > lost_rows.max()
        by_col = kept_cols.max() < lost_cols.min() or kept_cols.min() > lost_cols.max()
        assert by_row or by_col
        span = (lost_rows if by_row else lost_cols).size / (sparse > 0).sum()
        assert 0.15 < span < 0.85  # within CUT_SPAN of the returns' extent
    assert cut_returns(np.zeros((8, 8), np.float32), np.random.default_rng(0)).sum() == 0
    root = write_dataset(tmp_path / "data", {"train": 1}, size=256)
    store = SampleStore(root)
    sample = store.load(store.records[0])
    sample.meta["intrinsics"] = PAPER_CAMERA.intrinsics().scaled(256, 256).as_dict()
    write_sample(root / store.records[0]["file"], sample)
    plain = TileDataset(store, store.records, tile=None, stride=64)[0]
    cut = TileDataset(store, store.records, tile=None, stride=64, field_cut_share=1.0)[0]
    assert torch.equal(cut["depth"], plain["depth"]) and torch.equal(cut["gray"], plain["gray"])
    assert 0 < (cut["sparse"] > 0).sum() < (plain["sparse"] > 0).sum()
    with pytest.raises(ValueError, match="field_cut_share"):
        TileDataset(store, store.records, stride=64, field_cut_share=-0.1)
