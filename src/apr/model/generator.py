"""The GQN generator: ConvDRAW (Eslami et al. 2018), and the negative ELBO that trains it and the encoder.

Per generation step l (hidden states at 16x16, canvas u at 64x64):
    prior      p_l(z | h_g)                       conv 5x5 on the generator state
    inference  h_e <- ConvLSTM_e(x_q, v_q, r, h_g, u)
    posterior  q_l(z | h_e)                       conv 5x5 on the inference state
    generator  h_g <- ConvLSTM_g(z, v_q, r, u)     z ~ q_l while training, ~ p_l when sampling
    canvas     u <- u + ConvTranspose_4x4/4(h_g)
The image mean is sigmoid(conv 1x1(u)), the likelihood N(x_q | mean, sigma^2), the loss
    -ELBO = -log N(x_q | mean, sigma^2) + sum_l KL(q_l || p_l)      (nats per image, summed over pixels).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from apr.model.encoder import tile


class ConvLSTMCell(nn.Module):
    """A convolutional LSTM: the four gates from one conv over [input, h]."""

    def __init__(self, in_channels: int, hidden_channels: int, kernel: int) -> None:
        super().__init__()
        self.gates = nn.Conv2d(in_channels + hidden_channels, 4 * hidden_channels, kernel, padding=kernel // 2)

    def forward(self, x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """x: (B, I, S, S); state (h, c): (B, H, S, S) each. Returns the new (h, c)."""
        h, c = state
        forget, inp, out, cand = self.gates(torch.cat([x, h.to(x.dtype)], dim=1)).chunk(4, dim=1)
        c = torch.sigmoid(forget) * c + torch.sigmoid(inp) * torch.tanh(cand)  # c stays fp32 under autocast
        h = torch.sigmoid(out) * torch.tanh(c)
        return h, c


def _gaussian(params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, 2Z, S, S) head output -> mean, std (softplus keeps std positive and smooth)."""
    mean, raw_std = params.float().chunk(2, dim=1)
    return mean, F.softplus(raw_std) + 1e-4


def gaussian_kl(mean_q: torch.Tensor, std_q: torch.Tensor, mean_p: torch.Tensor, std_p: torch.Tensor) -> torch.Tensor:
    """KL(N(mean_q, std_q^2) || N(mean_p, std_p^2)), elementwise."""
    var_ratio = (std_q / std_p) ** 2
    return 0.5 * (var_ratio + ((mean_q - mean_p) / std_p) ** 2 - 1.0 - torch.log(var_ratio))


class ConvDRAWGenerator(nn.Module):
    """GQN's generator: a ConvDRAW conditioned on the scene representation r and the query pose."""

    def __init__(
        self,
        image_channels: int,
        pose_dim: int,
        representation_channels: int = 256,
        lstm_channels: int = 128,
        latent_channels: int = 3,
        canvas_channels: int = 128,
        steps: int = 12,
        kernel: int = 5,
        scale: int = 4,
    ) -> None:
        super().__init__()
        self.steps, self.scale, self.latent_channels = steps, scale, latent_channels
        self.lstm_channels, self.canvas_channels = lstm_channels, canvas_channels
        query_channels = image_channels * scale * scale  # the query image by space-to-depth
        self.canvas_down = nn.Conv2d(canvas_channels, canvas_channels, kernel_size=scale, stride=scale)
        condition = pose_dim + representation_channels + canvas_channels  # (v_q, r, u) at 16x16
        self.inference_core = ConvLSTMCell(query_channels + condition + lstm_channels, lstm_channels, kernel)
        self.generator_core = ConvLSTMCell(latent_channels + condition, lstm_channels, kernel)
        self.prior_head = nn.Conv2d(lstm_channels, 2 * latent_channels, kernel, padding=kernel // 2)
        self.posterior_head = nn.Conv2d(lstm_channels, 2 * latent_channels, kernel, padding=kernel // 2)
        self.write = nn.ConvTranspose2d(lstm_channels, canvas_channels, kernel_size=scale, stride=scale)
        self.to_image = nn.Conv2d(canvas_channels, image_channels, kernel_size=1)

    def noise_shape(self, batch: int, r_size: int) -> tuple[int, ...]:
        """Shape of the standard-normal noise one pass needs: (L, B, Z, S, S)."""
        return (self.steps, batch, self.latent_channels, r_size, r_size)

    def _initial_state(self, r: torch.Tensor) -> tuple[torch.Tensor, ...]:
        batch, _, size, _ = r.shape
        hidden = r.new_zeros((batch, self.lstm_channels, size, size), dtype=torch.float32)
        canvas = r.new_zeros((batch, self.canvas_channels, size * self.scale, size * self.scale))
        return hidden, hidden.clone(), canvas.float()

    def forward(
        self, r: torch.Tensor, query_pose: torch.Tensor, query_image: torch.Tensor, noise: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Reconstruct the query view through the posterior.

        Args:
            r: (B, R, 16, 16) scene representation of the context views.
            query_pose: (B, P), the query view's (v, g).
            query_image: (B, C, 64, 64) in [0, 1], the view to predict.
            noise: (L, B, Z, 16, 16) standard normal, drawn by the caller (seeded, compile-friendly).

        Returns:
            mean image (B, C, 64, 64) in [0, 1] (fp32) and the KL summed over steps, latents, positions (B,).
        """
        h_g, c_g, canvas = self._initial_state(r)
        h_e, c_e = h_g.clone(), c_g.clone()
        pose = tile(query_pose.to(r.dtype), r.shape[-1])
        query = F.pixel_unshuffle(query_image, self.scale)  # (B, C * 16, 16, 16), lossless
        kl = r.new_zeros(r.shape[0], dtype=torch.float32)
        for step in range(self.steps):
            condition = torch.cat([pose, r, self.canvas_down(canvas)], dim=1)
            prior_mean, prior_std = _gaussian(self.prior_head(h_g))
            h_e, c_e = self.inference_core(torch.cat([query, condition, h_g.to(condition.dtype)], dim=1), (h_e, c_e))
            post_mean, post_std = _gaussian(self.posterior_head(h_e))
            z = post_mean + post_std * noise[step]
            kl = kl + gaussian_kl(post_mean, post_std, prior_mean, prior_std).flatten(1).sum(dim=1)
            h_g, c_g = self.generator_core(torch.cat([z.to(condition.dtype), condition], dim=1), (h_g, c_g))
            canvas = canvas + self.write(h_g)
        return torch.sigmoid(self.to_image(canvas).float()), kl

    @torch.no_grad()
    def sample(self, r: torch.Tensor, query_pose: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """Predict the query view from the prior (for pictures). Shapes as in ``forward``; (B, C, 64, 64)."""
        h_g, c_g, canvas = self._initial_state(r)
        pose = tile(query_pose.to(r.dtype), r.shape[-1])
        for step in range(self.steps):
            condition = torch.cat([pose, r, self.canvas_down(canvas)], dim=1)
            prior_mean, prior_std = _gaussian(self.prior_head(h_g))
            z = prior_mean + prior_std * noise[step]
            h_g, c_g = self.generator_core(torch.cat([z.to(condition.dtype), condition], dim=1), (h_g, c_g))
            canvas = canvas + self.write(h_g)
        return torch.sigmoid(self.to_image(canvas).float())


def gqn_elbo_loss(
    generator: nn.Module,
    r: torch.Tensor,
    query_pose: torch.Tensor,
    query_image: torch.Tensor,
    sigma: float,
    noise: torch.Tensor,
    channel_weights: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Negative ELBO of GQN (Eslami et al. 2018), in nats per image, averaged over the batch.

    Args:
        generator: a ConvDRAWGenerator (or its compiled wrapper).
        r: (B, R, 16, 16), computed WITH gradient: this loss is what trains the encoder.
        query_pose: (B, P); query_image: (B, C, 64, 64) in [0, 1]; noise: (L, B, Z, 16, 16).
        sigma: pixel standard deviation of the Gaussian likelihood (annealed by the caller).
        channel_weights: (C,) weights of each channel's negative log-likelihood; None: all 1 (the ELBO itself).

    Returns:
        the loss (scalar) and its metrics (detached scalars): gqn/elbo_loss, gqn/nll, gqn/kl, gqn/mse.
    """
    mean, kl = generator(r, query_pose, query_image, noise)
    target = query_image.float()
    squared_error = (target - mean) ** 2
    nll_per_pixel = squared_error / (2 * sigma**2) + math.log(sigma) + 0.5 * math.log(2 * math.pi)
    if channel_weights is not None:
        nll_per_pixel = nll_per_pixel * channel_weights.view(1, -1, 1, 1)
    nll = nll_per_pixel.flatten(1).sum(dim=1)  # (B,)
    loss = (nll + kl).mean()
    metrics = {
        "gqn/elbo_loss": loss.detach(),
        "gqn/nll": nll.mean().detach(),
        "gqn/kl": kl.mean().detach(),
        "gqn/mse": squared_error.mean().detach(),
    }
    return loss, metrics
