"""Encoder LSTM -> autoregressive LSTM decoder on displacements (PyTorch, CPU).

The encoder reads the ``obs - 1`` observed displacements (divided by a scalar scale, the
standard deviation of the training displacements); the decoder, initialised with the
encoder's state, emits one displacement per future step and feeds it back. Training
minimises the mean squared error of the future positions (cumulative displacements) with
Adam, with random rotations of each batch as augmentation (pedestrian motion has no
preferred direction across scenes). Everything is seeded; the weights (``model.pt``),
the normalisation and the configuration (``config.json``) are saved together.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from conformal_control.core.progress import progress
from conformal_control.predictors.learned import WindowPredictor, synthetic_windows

__all__ = [
    "UNIT_TEST_PARAMS",
    "UNIT_TEST_WEIGHTS",
    "LSTMPredictor",
    "Seq2Seq",
    "make_unit_test_weights",
]

#: Tiny weights shipped with the package for the contract kit (8 units, 2 epochs on 256
#: seeded synthetic walks), so that ``_unit_test_params`` never trains anything.
UNIT_TEST_WEIGHTS = Path(__file__).resolve().parent / "unit_test_weights"
UNIT_TEST_PARAMS: dict[str, Any] = {"hidden": 8, "epochs": 2, "batch_size": 64}


class Seq2Seq(nn.Module):
    """Encoder LSTM over displacements, LSTMCell decoder rolled out ``horizon`` steps."""

    def __init__(self, hidden: int, layers: int, horizon: int) -> None:
        super().__init__()
        self.horizon = horizon
        self.embed = nn.Linear(2, hidden)
        self.encoder = nn.LSTM(hidden, hidden, num_layers=layers, batch_first=True)
        self.decoder = nn.LSTMCell(hidden, hidden)
        self.head = nn.Linear(hidden, 2)

    def forward(self, disp: torch.Tensor) -> torch.Tensor:
        """(B, obs-1, 2) normalised displacements -> (B, horizon, 2) displacements."""
        _, (h, c) = self.encoder(torch.relu(self.embed(disp)))
        h, c = h[-1], c[-1]
        step = disp[:, -1]
        out = []
        for _ in range(self.horizon):
            h, c = self.decoder(torch.relu(self.embed(step)), (h, c))
            step = step + self.head(h)  # residual: change of displacement
            out.append(step)
        return torch.stack(out, dim=1)


class LSTMPredictor(WindowPredictor, run_values={"random_state": "seed"}):
    """Encoder-decoder LSTM on past displacements (PyTorch), trained on ETH/UCY.

    Parameters
    ----------
    hidden, layers : int
        Width and depth of the encoder (the decoder is one LSTMCell of width ``hidden``).
    epochs, batch_size, lr : training schedule (Adam).
    rotate : bool
        Augment training batches with random rotations.
    obs, horizon : int
        Observed and predicted samples of the training windows.
    model_dt : float
        Spacing of the training windows (s); queries at another spacing are resampled.
    weights : str or None
        Folder written by ``save`` / ``conformal-control train-predictor``.
    random_state : int
        Seed of initialisation, shuffling and augmentation.
    threads : int
        torch CPU threads while training and predicting.
    """

    def __init__(
        self,
        hidden: int = 64,
        layers: int = 1,
        epochs: int = 10,
        batch_size: int = 256,
        lr: float = 3e-3,
        rotate: bool = True,
        obs: int = 8,
        horizon: int = 12,
        model_dt: float = 0.4,
        weights: str | None = None,
        random_state: int = 0,
        threads: int = 1,
    ) -> None:
        self.hidden = hidden
        self.layers = layers
        self.epochs = epochs
        self.batch_size = batch_size
        self.lr = lr
        self.rotate = rotate
        self.obs = obs
        self.horizon = horizon
        self.model_dt = model_dt
        self.weights = weights
        self.random_state = random_state
        self.threads = threads

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        """The tiny weights shipped in the package (see :func:`make_unit_test_weights`)."""
        return [{**UNIT_TEST_PARAMS, "weights": str(UNIT_TEST_WEIGHTS)}]

    # ------------------------------------------------------------------ training
    def _fit_arrays(self, disp: np.ndarray, target: np.ndarray) -> None:
        torch.set_num_threads(int(self.threads))
        torch.manual_seed(int(self.random_state))
        rng = np.random.default_rng(int(self.random_state))
        scale = float(np.std(disp)) or 1.0
        net = Seq2Seq(int(self.hidden), int(self.layers), int(self.horizon))
        opt = torch.optim.Adam(net.parameters(), lr=float(self.lr))
        x_all = torch.as_tensor(disp / scale, dtype=torch.float32)
        y_all = torch.as_tensor(target / scale, dtype=torch.float32)
        n = len(x_all)
        losses = []
        net.train()
        bar = progress(int(self.epochs), f"training lstm on {n} windows", "epochs")
        for _ in range(int(self.epochs)):
            order = rng.permutation(n)
            total = 0.0
            for s in range(0, n, int(self.batch_size)):
                idx = order[s : s + int(self.batch_size)]
                x, y = x_all[idx], y_all[idx]
                if self.rotate:
                    th = torch.as_tensor(rng.uniform(0, 2 * np.pi, len(idx)), dtype=torch.float32)
                    rot = torch.stack(
                        [torch.cos(th), -torch.sin(th), torch.sin(th), torch.cos(th)], dim=-1
                    ).view(-1, 1, 2, 2)
                    x = (rot @ x.unsqueeze(-1)).squeeze(-1)
                    y = (rot @ y.unsqueeze(-1)).squeeze(-1)
                pred = torch.cumsum(net(x), dim=1)
                loss = torch.mean((pred - y) ** 2)
                opt.zero_grad()
                loss.backward()
                opt.step()
                total += float(loss.detach()) * len(idx)
            losses.append(total / n)
            bar.set_postfix(f"loss {losses[-1]:.4g}")
            bar.update()
        bar.close()
        net.eval()
        self.net_ = net
        self.scale_ = scale
        self.train_losses_ = losses

    def _predict_offsets(self, disp: np.ndarray) -> np.ndarray:
        torch.set_num_threads(int(self.threads))
        with torch.no_grad():
            x = torch.as_tensor(disp / self.scale_, dtype=torch.float32)
            out = torch.cumsum(self.net_(x), dim=1).numpy().astype(float)
        return out * self.scale_

    def _save_model(self, folder: Path) -> None:
        torch.save(self.net_.state_dict(), folder / "model.pt")
        norm = {"scale": self.scale_, "train_losses": getattr(self, "train_losses_", [])}
        (folder / "normalisation.json").write_text(json.dumps(norm, indent=2))

    def _load_model(self, folder: Path, config: dict[str, Any]) -> None:
        saved = config["params"]
        net = Seq2Seq(int(saved["hidden"]), int(saved["layers"]), int(saved["horizon"]))
        net.load_state_dict(torch.load(folder / "model.pt", weights_only=True))
        net.eval()
        self.net_ = net
        self.scale_ = float(json.loads((folder / "normalisation.json").read_text())["scale"])


def make_unit_test_weights(folder: str | Path = UNIT_TEST_WEIGHTS) -> Path:
    """Train the tiny seeded model of ``_unit_test_params`` and save it to ``folder``.

    The package ships its output; the plugin's tests re-create it in a temporary folder
    and check that it still predicts the same (re-run this after changing the model).
    """
    model = LSTMPredictor(**UNIT_TEST_PARAMS).fit(*synthetic_windows(), dt=0.4)
    return model.save(folder)
