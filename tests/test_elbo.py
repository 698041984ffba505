"""The generator's loss against hand-computed values: the Gaussian KL, the negative ELBO on a stub generator whose
mean image and KL are fixed, and the KL that ConvDRAW sums over its steps when its prior and posterior are constant.

The other tests of the GQN are relative (a loss falls, a prediction beats the mean image); a loss with its sign
flipped or without its KL term would pass them. Every expected number here is worked out in its comment.
"""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from apr.model.generator import ConvDRAWGenerator, gaussian_kl, gqn_elbo_loss

HALF_LOG_TWO_PI = 0.5 * math.log(2 * math.pi)  # 0.91893853...


@pytest.mark.parametrize(
    ("mean_q", "std_q", "mean_p", "std_p", "kl"),
    [
        # ln(std_p / std_q) + (std_q^2 + (mean_q - mean_p)^2) / (2 std_p^2) - 1/2
        (1.0, 0.5, 0.0, 1.0, math.log(2) + (0.25 + 1.0) / 2 - 0.5),  # 0.81814718
        (0.0, 2.0, 1.0, 1.0, math.log(0.5) + (4.0 + 1.0) / 2 - 0.5),  # 1.30685282: not the same KL backwards
        (-1.0, 1.0, 2.0, 3.0, math.log(3) + (1.0 + 9.0) / 18 - 0.5),  # 1.15416784
        (0.3, 0.7, 0.3, 0.7, 0.0),  # a distribution from itself
    ],
)
def test_the_gaussian_kl_is_the_closed_form(mean_q: float, std_q: float, mean_p: float, std_p: float, kl: float):
    value = gaussian_kl(*(torch.tensor([x], dtype=torch.float64) for x in (mean_q, std_q, mean_p, std_p)))
    assert value.item() == pytest.approx(kl, abs=1e-12)


class StubGenerator(nn.Module):
    """A generator whose reconstruction is a fixed mean image and whose KL is fixed, both parameters (so that the
    loss's gradient can be read off them); it ignores r, the pose and the noise."""

    def __init__(self, mean: torch.Tensor, kl: torch.Tensor):
        super().__init__()
        self.mean, self.kl = nn.Parameter(mean.clone()), nn.Parameter(kl.clone())

    def forward(self, r: torch.Tensor, pose: torch.Tensor, image: torch.Tensor, noise: torch.Tensor):
        return self.mean, self.kl


def test_the_negative_elbo_of_a_stub_is_the_hand_computed_one_and_descends_toward_the_image_and_a_lower_kl():
    """Two 1x2x2 images, a mean image of 0.5 everywhere, sigma 0.5, KLs 0.25 and 1.0 nats.

    Per pixel, -log N(x | m, sigma^2) = (x - m)^2 / (2 sigma^2) + ln sigma + ln(2 pi) / 2, with
    ln 0.5 + ln(2 pi) / 2 = 0.22579135. Image 0 is the mean itself: nll 4 * 0.22579135 = 0.90316541. Image 1 is
    (0, 1, 0.5, 0.5): squared errors 0.25, 0.25, 0, 0, each over 2 * 0.25, adding 1.0: nll 1.90316541. The loss is
    the batch mean of nll + KL: (0.90316541 + 0.25 + 1.90316541 + 1.0) / 2 = 2.02816541.
    """
    images = torch.tensor([[[[0.5, 0.5], [0.5, 0.5]]], [[[0.0, 1.0], [0.5, 0.5]]]], dtype=torch.float64)
    stub = StubGenerator(torch.full_like(images, 0.5), torch.tensor([0.25, 1.0], dtype=torch.float64))
    loss, metrics = gqn_elbo_loss(stub, torch.zeros(2, 1, 1, 1), torch.zeros(2, 1), images, 0.5, torch.zeros(1))
    per_pixel = math.log(0.5) + HALF_LOG_TWO_PI
    assert per_pixel == pytest.approx(0.2257913526, abs=1e-10)
    nll = [4 * per_pixel, 4 * per_pixel + 1.0]
    assert loss.item() == pytest.approx((nll[0] + 0.25 + nll[1] + 1.0) / 2, abs=1e-12)
    assert loss.item() == pytest.approx(2.0281654106, abs=1e-10)
    assert metrics["gqn/elbo_loss"].item() == pytest.approx(loss.item(), abs=1e-12)
    assert metrics["gqn/nll"].item() == pytest.approx((nll[0] + nll[1]) / 2, abs=1e-12)
    assert metrics["gqn/kl"].item() == pytest.approx(0.625, abs=1e-12)
    assert metrics["gqn/mse"].item() == pytest.approx(0.5 / 8, abs=1e-12)

    loss.backward()
    # d loss / d KL_i = 1 / B: descending the loss lowers each KL.
    torch.testing.assert_close(stub.kl.grad, torch.tensor([0.5, 0.5], dtype=torch.float64))
    # d loss / d m = (m - x) / sigma^2 / B: descending moves the mean toward the image (0 where it is the image).
    expected = torch.tensor([[[[0.0, 0.0], [0.0, 0.0]]], [[[1.0, -1.0], [0.0, 0.0]]]], dtype=torch.float64)
    torch.testing.assert_close(stub.mean.grad, expected)


def test_a_larger_sigma_weighs_the_pixel_error_less_and_adds_its_log_per_pixel():
    """sigma 2 for image 1 of the test above alone: 4 * (ln 2 + ln(2 pi) / 2) + 0.5 / (2 * 4) = 6.43883...,
    plus the KL of 1.0."""
    image = torch.tensor([[[[0.0, 1.0], [0.5, 0.5]]]], dtype=torch.float64)
    stub = StubGenerator(torch.full_like(image, 0.5), torch.tensor([1.0], dtype=torch.float64))
    loss, _ = gqn_elbo_loss(stub, torch.zeros(1, 1, 1, 1), torch.zeros(1, 1), image, 2.0, torch.zeros(1))
    assert loss.item() == pytest.approx(4 * (math.log(2) + HALF_LOG_TWO_PI) + 0.5 / 8 + 1.0, abs=1e-12)


def softplus(x: float) -> float:
    return math.log1p(math.exp(x))


def test_convdraw_sums_the_kl_of_posterior_from_prior_over_steps_latents_and_positions():
    """With the prior's and the posterior's heads zeroed but for their biases, every step gives every latent channel
    at every position the same two Gaussians, whatever the image, the pose and r: mean = bias, std = softplus(raw
    bias) + 1e-4. The KL is then 3 steps x 2x2 positions x the sum over the 2 channels of KL(q || p).

    Channel 0: both stds softplus(0) + 1e-4 = 0.693247, means 0.5 and 0: KL = 0.25 / (2 * 0.480592) = 0.260096.
    Channel 1: std_q = softplus(1) + 1e-4 = 1.313362, std_p = softplus(-0.5) + 1e-4 = 0.474177, means -1 and 0.2:
    KL = ln(0.474177 / 1.313362) + (1.724920 + 1.44) / (2 * 0.224844) - 0.5 = -1.018737 + 7.038011 - 0.5 = 5.519274.
    Per image: 12 * 5.779370 = 69.352442."""
    torch.manual_seed(0)
    generator = ConvDRAWGenerator(image_channels=3, pose_dim=2, representation_channels=4, lstm_channels=4,
                                  latent_channels=2, canvas_channels=2, steps=3, kernel=3)  # fmt: skip
    posterior = {"mean": (0.5, -1.0), "raw": (0.0, 1.0)}
    prior = {"mean": (0.0, 0.2), "raw": (0.0, -0.5)}
    with torch.no_grad():
        for head, values in ((generator.posterior_head, posterior), (generator.prior_head, prior)):
            head.weight.zero_()
            head.bias.copy_(torch.tensor([*values["mean"], *values["raw"]]))
    per_channel = []
    for channel in range(2):
        std_q = softplus(posterior["raw"][channel]) + 1e-4
        std_p = softplus(prior["raw"][channel]) + 1e-4
        gap = posterior["mean"][channel] - prior["mean"][channel]
        per_channel.append(math.log(std_p / std_q) + (std_q**2 + gap**2) / (2 * std_p**2) - 0.5)
    expected = 3 * 4 * sum(per_channel)
    assert expected == pytest.approx(69.352442, abs=1e-6)
    r, images = torch.randn(2, 4, 2, 2), torch.rand(2, 3, 8, 8)  # the generator computes in fp32
    _, kl = generator(r, torch.randn(2, 2), images, torch.randn(generator.noise_shape(2, 2)))
    torch.testing.assert_close(kl, torch.full((2,), expected), rtol=1e-5, atol=0)


def test_a_channel_weight_scales_that_channels_nll_alone():
    """``gqn_mask_weight``'s path: image 1 of the first test as a 2-channel 1x2 image, channel 0 (0, 1) and channel 1
    (0.5, 0.5), mean 0.5, sigma 0.5. Unweighted: channel 0 costs 2 * 0.22579135 + 1.0, channel 1 2 * 0.22579135, the
    nll 1.90316541. Channel 1 weighted 3: 1.45158271 + 3 * 0.45158271 = 2.80633083, plus the KL of 1.0."""
    image = torch.tensor([[[[0.0, 1.0]], [[0.5, 0.5]]]], dtype=torch.float64)
    stub = StubGenerator(torch.full_like(image, 0.5), torch.tensor([1.0], dtype=torch.float64))
    args = (stub, torch.zeros(1, 1, 1, 1), torch.zeros(1, 1), image, 0.5, torch.zeros(1))
    per_pixel = math.log(0.5) + HALF_LOG_TWO_PI
    plain, _ = gqn_elbo_loss(*args)
    assert plain.item() == pytest.approx(4 * per_pixel + 1.0 + 1.0, abs=1e-12)
    weighted, metrics = gqn_elbo_loss(*args, channel_weights=torch.tensor([1.0, 3.0], dtype=torch.float64))
    assert weighted.item() == pytest.approx((2 * per_pixel + 1.0) + 3 * 2 * per_pixel + 1.0, abs=1e-12)
    assert weighted.item() == pytest.approx(3.8063308, abs=1e-6)
    assert metrics["gqn/mse"].item() == pytest.approx(0.5 / 4, abs=1e-12)  # the error itself is unweighted
