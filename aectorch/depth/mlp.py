"""`DepthMLP`: the paper's two-layer network from the four eye angles to the distance (sec. 2.4).

It is MATLAB's ``fitnet(10)`` as the paper used it: a hidden layer of sigmoid
neurons, a linear output, and ``mapminmax`` on the inputs and the targets, so
that the network itself only ever sees values in [-1, 1]. Training belongs to
`aectorch.depth.fit_levenberg_marquardt`, which sets the normalisation from the
data and can start from `nguyen_widrow_` weights, as ``train``/``init`` do in MATLAB.
"""

from __future__ import annotations

import torch
from torch import nn

from aectorch._checks import check_int

__all__ = ["DepthMLP", "mapminmax", "mapminmax_reverse", "nguyen_widrow_", "ACTIVATIONS"]

#: Hidden transfer functions: MATLAB's tansig (``2 / (1 + exp(-2n)) - 1``, which is
#: ``tanh``) and logsig (the logistic). The tuple is (function, active input range),
#: the range Nguyen-Widrow spreads the net inputs over (MATLAB's ``f('active')``).
ACTIVATIONS = {
    "tansig": (torch.tanh, (-2.0, 2.0)),
    "logsig": (torch.sigmoid, (-4.0, 4.0)),
}

# mapminmax treats a column as constant (and passes it through) when its range is
# zero or not finite, or when the gain would exceed this (MATLAB's own threshold).
_MAX_GAIN = 1e14


def _gain(minimum: torch.Tensor, maximum: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """mapminmax's safe ``gain`` and ``offset``: identity for constant columns."""
    span = maximum - minimum
    gain = 2.0 / span
    fix = (span == 0) | ~torch.isfinite(span) | (gain.abs() > _MAX_GAIN)
    gain = torch.where(fix, torch.ones_like(gain), gain)
    offset = torch.where(fix, torch.full_like(minimum, -1.0), minimum)
    return gain, offset


def mapminmax(x: torch.Tensor, minimum: torch.Tensor, maximum: torch.Tensor) -> torch.Tensor:
    """Map each column of `x` from [minimum, maximum] to [-1, 1], like MATLAB's ``mapminmax``.

    ``y = (x - minimum) * 2 / (maximum - minimum) - 1``. A constant column
    (``maximum == minimum``, or a non-finite range) is passed through unchanged,
    as mapminmax does: no division by zero.

    Args:
        x: values `[..., F]`.
        minimum, maximum: per-column range `[F]`.

    Returns:
        `[..., F]`, in [-1, 1] for values inside the range.

    Example:
        >>> import torch
        >>> x = torch.tensor([[1.0, 5.0], [3.0, 5.0]])
        >>> mapminmax(x, x.amin(0), x.amax(0))
        tensor([[-1.,  5.],
                [ 1.,  5.]])
    """
    gain, offset = _gain(minimum, maximum)
    return (x - offset) * gain - 1.0


def mapminmax_reverse(y: torch.Tensor, minimum: torch.Tensor, maximum: torch.Tensor) -> torch.Tensor:
    """Inverse of `mapminmax`: from [-1, 1] back to [minimum, maximum] per column.

    Shape:
        y: `[..., F]`; minimum, maximum: `[F]`; returns `[..., F]`.

    Example:
        >>> import torch
        >>> mapminmax_reverse(torch.tensor([[-1.0], [0.0], [1.0]]), torch.tensor([1.0]), torch.tensor([3.0]))
        tensor([[1.],
                [2.],
                [3.]])
    """
    gain, offset = _gain(minimum, maximum)
    return (y + 1.0) / gain + offset


class DepthMLP(nn.Module):
    """Two-layer perceptron from eye angles to distance, with mapminmax in and out.

    ``d = denorm(W2 sigma(W1 norm(q) + b1) + b2)``: the hidden layer is MATLAB's
    tansig (``tanh``) by default, the paper's "sigmoid transfer function" as
    ``fitnet`` builds it; ``activation="logsig"`` gives the logistic instead.
    ``norm``/``denorm`` map each input and output column linearly between its
    data range and [-1, 1] (`mapminmax`). The ranges are buffers (saved in the
    state dict); they start as [-1, 1] (identity) until `set_normalisation`
    sets them from training data, which `fit_levenberg_marquardt` does.

    Args:
        in_features: inputs per sample (the paper: 4 eye angles q1..q4).
        hidden: hidden neurons (the paper: 10).
        out_features: outputs per sample (the paper: 1, the distance).
        activation: ``"tansig"`` (default) or ``"logsig"``.
        dtype, device: of parameters and buffers (default: torch's defaults).

    Shape:
        forward: `[..., in_features]` -> `[..., out_features]`.

    Example:
        >>> import torch
        >>> from aectorch.depth import DepthMLP
        >>> model = DepthMLP()
        >>> q_deg = torch.tensor([[5.71, 3.44, -5.71, 3.44], [1.91, 1.15, -1.91, 1.15]])
        >>> d_m = torch.tensor([[1.0], [3.0]])
        >>> _ = model.set_normalisation(q_deg, d_m)
        >>> model(q_deg).shape
        torch.Size([2, 1])
        >>> model.output_min, model.output_max
        (tensor([1.]), tensor([3.]))
    """

    def __init__(
        self,
        in_features: int = 4,
        hidden: int = 10,
        out_features: int = 1,
        *,
        activation: str = "tansig",
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        for name, value in (("in_features", in_features), ("hidden", hidden), ("out_features", out_features)):
            check_int(value, name)
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}")
        self.in_features, self.hidden_features, self.out_features = in_features, hidden, out_features
        self.activation = activation
        factory = {"dtype": dtype, "device": device}
        self.hidden = nn.Linear(in_features, hidden, **factory)
        self.output = nn.Linear(hidden, out_features, **factory)
        self.register_buffer("input_min", torch.full((in_features,), -1.0, **factory))
        self.register_buffer("input_max", torch.full((in_features,), 1.0, **factory))
        self.register_buffer("output_min", torch.full((out_features,), -1.0, **factory))
        self.register_buffer("output_max", torch.full((out_features,), 1.0, **factory))

    def extra_repr(self) -> str:
        return f"activation={self.activation!r}"

    @property
    def active_range(self) -> tuple[float, float]:
        """Net-input range where the hidden transfer function is not saturated."""
        return ACTIVATIONS[self.activation][1]

    @torch.no_grad()
    def set_normalisation(self, inputs: torch.Tensor, targets: torch.Tensor) -> "DepthMLP":
        """Set the mapminmax ranges from data: the per-column min and max.

        Args:
            inputs: `[N, in_features]`.
            targets: `[N, out_features]` (or `[N]` when ``out_features == 1``).

        Returns:
            self.
        """
        inputs = torch.as_tensor(inputs)
        targets = torch.as_tensor(targets)
        if targets.ndim == 1 and self.out_features == 1:
            targets = targets[:, None]
        for name, value, width in (("inputs", inputs, self.in_features), ("targets", targets, self.out_features)):
            if value.ndim != 2 or value.shape[1] != width or value.shape[0] < 1:
                raise ValueError(f"{name} must have shape [N >= 1, {width}], got {tuple(value.shape)}")
            if not value.is_floating_point() or not torch.isfinite(value).all():
                raise ValueError(f"{name} must be finite floating-point values")
        if inputs.shape[0] != targets.shape[0]:
            raise ValueError(
                f"inputs and targets must have the same number of samples, got {inputs.shape[0]} and {targets.shape[0]}"
            )
        self.input_min.copy_(inputs.amin(0))
        self.input_max.copy_(inputs.amax(0))
        self.output_min.copy_(targets.amin(0))
        self.output_max.copy_(targets.amax(0))
        return self

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        """Distance (or whatever the targets were) for `inputs` `[..., in_features]`."""
        if inputs.shape[-1:] != (self.in_features,):
            raise ValueError(f"inputs must have shape [..., {self.in_features}], got {tuple(inputs.shape)}")
        sigma = ACTIVATIONS[self.activation][0]
        x = mapminmax(inputs, self.input_min, self.input_max)
        y = self.output(sigma(self.hidden(x)))
        return mapminmax_reverse(y, self.output_min, self.output_max)


@torch.no_grad()
def _nguyen_widrow_layer(
    layer: nn.Linear,
    generator: torch.Generator | None,
    active_range: tuple[float, float],
    constant_inputs: torch.Tensor | None = None,
) -> None:
    s, r_all = layer.weight.shape
    used = torch.ones(r_all, dtype=torch.bool) if constant_inputs is None else ~constant_inputs.cpu()
    r = int(used.sum())
    weight = torch.zeros(s, r_all, dtype=torch.float64)
    bias = torch.zeros(s, dtype=torch.float64)
    if r > 0:
        magnitude = 0.7 * s ** (1.0 / r)
        direction = torch.rand(s, r, generator=generator, dtype=torch.float64) * 2 - 1
        direction = direction / direction.norm(dim=1, keepdim=True).clamp_min(1e-300)
        w = magnitude * direction
        b = torch.zeros(s, dtype=torch.float64)
        if s > 1:
            b = magnitude * torch.linspace(-1.0, 1.0, s, dtype=torch.float64) * torch.sign(w[:, 0])
        # Net inputs of [-1, 1] to the transfer function's active range.
        half, mid = 0.5 * (active_range[1] - active_range[0]), 0.5 * (active_range[1] + active_range[0])
        weight[:, used] = half * w
        bias = half * b + mid
    layer.weight.copy_(weight)
    if layer.bias is not None:
        layer.bias.copy_(bias)


@torch.no_grad()
def _uniform_(layer: nn.Linear, generator: torch.Generator | None) -> None:
    for p in (layer.weight, layer.bias):
        if p is not None:
            p.copy_(torch.rand(p.shape, generator=generator, dtype=torch.float64) * 2 - 1)


def nguyen_widrow_(
    model: nn.Module,
    generator: torch.Generator | None = None,
    *,
    active_range: tuple[float, float] = (-2.0, 2.0),
) -> nn.Module:
    """Nguyen-Widrow initial weights, in place, as MATLAB's ``initnw`` gives them.

    A hidden layer of S neurons with R inputs (assumed in [-1, 1], which is what
    mapminmax delivers) gets weight rows of length ``0.7 S^(1/R)`` in random
    directions (uniform, row-normalised) and biases spread evenly over
    ``[-0.7 S^(1/R), 0.7 S^(1/R)]``, then both scaled to the transfer function's
    active input range. Weights from constant inputs are zero. A linear output
    layer has no finite active range: like ``initnw`` it gets uniform [-1, 1]
    weights and biases (``rands``).

    Which layers are which:
        * `DepthMLP`: ``hidden`` by Nguyen-Widrow with its activation's active range,
          constant input columns (by its normalisation buffers) excluded;
          ``output`` uniform.
        * `nn.Linear`: the layer by Nguyen-Widrow with `active_range`.
        * any other module: its `nn.Linear` submodules in registration order, all
          but the last by Nguyen-Widrow with `active_range` (a chain of
          tansig-like layers), the last uniform.

    Args:
        model: the module to initialise.
        generator: optional `torch.Generator` for reproducible weights.
        active_range: net-input range of the hidden transfer function
            (tansig's ``[-2, 2]``; logsig's is ``[-4, 4]``); ignored for `DepthMLP`.

    Returns:
        `model`.

    Example:
        >>> import torch
        >>> from aectorch.depth import DepthMLP, nguyen_widrow_
        >>> model = nguyen_widrow_(DepthMLP(), torch.Generator().manual_seed(0))
        >>> norms = model.hidden.weight.norm(dim=1)   # 2 * 0.7 * 10 ** (1 / 4) each
        >>> torch.allclose(norms, torch.full((10,), 1.4 * 10 ** 0.25))
        True
    """
    if not isinstance(model, nn.Module):
        raise TypeError(f"model must be an nn.Module, got {type(model).__name__}")
    if isinstance(model, DepthMLP):
        constant = _constant_columns(model.input_min, model.input_max)
        _nguyen_widrow_layer(model.hidden, generator, model.active_range, constant)
        _uniform_(model.output, generator)
        return model
    if isinstance(model, nn.Linear):
        _nguyen_widrow_layer(model, generator, active_range)
        return model
    layers = [m for m in model.modules() if isinstance(m, nn.Linear)]
    if not layers:
        raise ValueError(f"model must contain at least one nn.Linear layer, got none in {type(model).__name__}")
    for layer in layers[:-1]:
        _nguyen_widrow_layer(layer, generator, active_range)
    _uniform_(layers[-1], generator)
    return model


def _constant_columns(minimum: torch.Tensor, maximum: torch.Tensor) -> torch.Tensor:
    span = maximum - minimum
    return (span == 0) | ~torch.isfinite(span) | (2.0 / span).abs().gt(_MAX_GAIN)

