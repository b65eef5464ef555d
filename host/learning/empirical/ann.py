"""One-hidden-layer back-propagation network (Li 2021, section 4.4), written with numpy.

Why numpy and not a library: the network is tiny (5-16 inputs, 3-7 tanh hidden
nodes, one linear output), the project pins no ML framework, and scikit-learn's
MLPRegressor would add a dependency for ~100 lines whose every step (seeded
initialisation, full-batch gradient, early stopping, size choice) we want
visible and deterministic. Gradients are the textbook back-propagation of the
squared error; the update is Adam on the full batch (deterministic: no
mini-batch shuffling), so the same data and seed give bit-identical weights.

Protocol:

* inputs and target are standardised with the *training* part's mean and
  standard deviation (stored, so the exported network is a function of the raw
  temperature rises);
* a validation set is held out of the training data: a seeded random
  ``validation_fraction`` of the samples (``validation="random"``, default, as a
  back-propagation study splits its samples), or the last group
  (``validation="last_group"``: the last run or spindle cycle, so the net is
  stopped on a condition it has not seen; needs ``groups``);
  or leave-one-out (``validation="loo"``, Li 2021's sample size: 8 sweeps, 5
  inputs): every sample is held out once, the n networks of a size are trained in
  lockstep on the other n − 1 and the epoch count is the one with the smallest
  mean held-out squared error; the network kept is then trained on all n samples
  for that many epochs. ``validation="auto"`` (default) is leave-one-out up to
  ``LOO_MAX_SAMPLES`` samples and the random split above it;
* for every hidden size in ``hidden_sizes`` (3..7 as in the paper) the network
  is trained from a seeded initialisation, stopping when the validation RMSE has
  not improved for ``patience`` epochs (at most ``max_epochs``); the weights of
  the best validation epoch are kept;
* the size: Li 2021 compares the sizes by MSE and R² and takes the smallest of
  the near-equal ones (four nodes: 4, 5, 6 within 0.1 %, 3 and 7 worse by 14 %
  and 108 %). ``size_rule="smallest_near_best"`` (default): the fewest nodes whose
  validation MSE is within ``size_tolerance`` (5 %) of the lowest; ``"best"``: the
  lowest validation RMSE (ties: fewer nodes), the rule before issue 23.

With the random or last-group split the kept network is the one trained on the
training part only (early stopping needs the validation part untouched);
``statistics()`` reports the fit on all training data, the validation RMSE,
MSE and R² of every size and the epochs used.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.checks import check_predict_x, check_xy, finite_or_none

LOO_MAX_SAMPLES = 30  # validation="auto": leave-one-out up to this many samples (n networks per size), random above
VALIDATIONS = ("auto", "random", "last_group", "loo")
SIZE_RULES = ("smallest_near_best", "best")


class ANN:
    """y ≈ m + s·(v·tanh(W·z + b) + c), z = (x − μ)/σ; scikit-learn style.

    Parameters (keyword-only): ``hidden_sizes`` (candidates), ``validation``
    ("random" or "last_group"), ``validation_fraction`` (random), ``max_epochs``, ``patience``, ``learning_rate`` (Adam step),
    ``seed``. Learned: ``hidden_size_``, ``W_`` (h, p), ``b_`` (h,), ``v_`` (h,),
    ``c_``, ``x_mean_``, ``x_scale_``, ``y_mean_``, ``y_scale_``, ``validation_rmse_``
    ({size: RMSE}), ``epochs_`` ({size: epochs run}), ``best_epoch_``, ``rmse_``,
    ``rsquared_``, ``n_samples_``, ``names_``.
    """

    method = "ann"

    def __init__(self, *, hidden_sizes: Sequence[int] = (3, 4, 5, 6, 7), validation: str = "auto", validation_fraction: float = 0.2, max_epochs: int = 3000, patience: int = 200, learning_rate: float = 0.01, seed: int = 0, size_rule: str = "smallest_near_best", size_tolerance: float = 0.05, fit_intercept: bool = True) -> None:
        self.hidden_sizes = hidden_sizes
        self.validation = validation
        self.size_rule = size_rule
        self.size_tolerance = size_tolerance
        self.validation_fraction = validation_fraction
        self.max_epochs = max_epochs
        self.patience = patience
        self.learning_rate = learning_rate
        self.seed = seed
        self.fit_intercept = fit_intercept  # accepted for a uniform interface; the output bias is always fitted

    def _check(self):
        sizes = [self.hidden_sizes] if isinstance(self.hidden_sizes, int) else list(self.hidden_sizes)
        if not sizes or any(isinstance(h, bool) or not isinstance(h, (int, np.integer)) or h < 1 for h in sizes):
            raise EmpiricalDataError("ann: hidden_sizes must be positive integers, got %r" % (self.hidden_sizes,))
        if not 0.0 < float(self.validation_fraction) < 1.0:
            raise EmpiricalDataError("ann: validation_fraction must be in (0, 1), got %r" % (self.validation_fraction,))
        for key in ("max_epochs", "patience"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise EmpiricalDataError("ann: %s must be an integer >= 1, got %r" % (key, v))
        if not float(self.learning_rate) > 0:
            raise EmpiricalDataError("ann: learning_rate must be > 0, got %r" % (self.learning_rate,))
        if self.size_rule not in SIZE_RULES:
            raise EmpiricalDataError("ann: size_rule must be one of %s, got %r" % (", ".join(SIZE_RULES), self.size_rule))
        if isinstance(self.size_tolerance, bool) or not float(self.size_tolerance) >= 0:
            raise EmpiricalDataError("ann: size_tolerance must be a number >= 0, got %r" % (self.size_tolerance,))
        return [int(h) for h in sizes]

    def _choose_size(self, mse):
        """{size: validation MSE} -> the kept size (see the module docstring)."""
        if self.size_rule == "best":
            return min(mse, key=lambda h: (mse[h], h))
        lo = min(mse.values())
        return min(h for h, v in mse.items() if v <= lo * (1.0 + float(self.size_tolerance)))

    def fit(self, X: np.ndarray, y: np.ndarray, names: Sequence[str] | None = None, groups: np.ndarray | None = None) -> ANN:
        sizes = self._check()
        X, y, names = check_xy(X, y, names, None, "ANN")
        n, p = X.shape
        val = np.zeros(n, bool)
        if self.validation not in VALIDATIONS:
            raise EmpiricalDataError("ann: validation must be one of %s, got %r" % (", ".join(VALIDATIONS), self.validation))
        mode = self.validation if self.validation != "auto" else ("loo" if n <= LOO_MAX_SAMPLES else "random")
        if mode == "loo":
            return self._fit_loo(X, y, names, sizes)
        if mode == "last_group":
            if groups is None or np.unique(groups).size < 2:
                raise EmpiricalDataError("ann: validation='last_group' needs at least 2 groups (runs or spindle cycles)")
            groups = np.asarray(groups)
            order = list(dict.fromkeys(groups.tolist()))
            val = groups == order[-1]
            self.validation_ = "last group (%s): %d samples" % (order[-1], int(val.sum()))
        else:
            rng = np.random.default_rng([int(self.seed), 7])
            val[rng.permutation(n)[: max(1, int(round(self.validation_fraction * n)))]] = True
            self.validation_ = "seeded random %.0f %% of the samples: %d" % (100 * self.validation_fraction, int(val.sum()))
        tr = ~val
        # more weights than samples is allowed (early stopping on the validation part is the regulariser),
        # but fewer training samples than a linear fit of the inputs needs is not
        if tr.sum() < p + 2 or val.sum() < 1:
            raise EmpiricalDataError("ANN: %d training and %d validation samples for %d inputs; need at least %d training samples and 1 validation sample"
                                     % (int(tr.sum()), int(val.sum()), p, p + 2))
        self.x_mean_ = X[tr].mean(axis=0)
        self.x_scale_ = X[tr].std(axis=0)
        self.x_scale_[self.x_scale_ == 0] = 1.0
        self.y_mean_ = float(y[tr].mean())
        self.y_scale_ = float(y[tr].std()) or 1.0
        Z = (X - self.x_mean_) / self.x_scale_
        t = (y - self.y_mean_) / self.y_scale_
        self.validation_rmse_, self.epochs_, fitted = {}, {}, {}
        sst_v = float(((y[val] - y[val].mean()) ** 2).sum())
        self.validation_r2_ = {}
        for h in sizes:
            params, rmse, epochs, best_epoch = self._train(Z[tr], t[tr], Z[val], t[val], h)
            assert rmse is not None  # early stopping (no epochs given) measures it
            self.validation_rmse_[h] = rmse * self.y_scale_
            self.validation_r2_[h] = 1.0 - val.sum() * self.validation_rmse_[h] ** 2 / sst_v if sst_v > 0 else float("nan")
            self.epochs_[h] = epochs
            fitted[h] = (params, best_epoch)
        self.hidden_size_ = self._choose_size({h: v ** 2 for h, v in self.validation_rmse_.items()})
        (self.W_, self.b_, self.v_, self.c_), self.best_epoch_ = fitted[self.hidden_size_]
        self.n_train_, self.n_validation_ = int(tr.sum()), int(val.sum())
        return self._finish(X, y, names)

    def _finish(self, X, y, names):
        self.names_ = names
        self.n_samples_ = int(y.size)
        r = y - self.predict(X)
        self.rmse_ = float(np.sqrt(np.mean(r**2)))
        sst = float(((y - y.mean()) ** 2).sum())
        self.rsquared_ = 1.0 - float(r @ r) / sst if sst > 0 else float("nan")
        return self

    def _fit_loo(self, X, y, names, sizes):
        """Leave-one-out: per size, n networks (each without one sample) trained in lockstep; the epoch count with the
        smallest mean held-out squared error; the kept network trained on all samples for that many epochs."""
        n, p = X.shape
        if n - 1 < p + 2:
            raise EmpiricalDataError("ANN: leave-one-out leaves %d training and 1 validation sample for %d inputs; need at least %d samples"
                                     % (n - 1, p, p + 3))
        self.validation_ = "leave-one-out over %d samples" % n
        keep = ~np.eye(n, dtype=bool)
        Xf = np.stack([X[k] for k in keep])  # (n folds, n - 1, p)
        yf = np.stack([y[k] for k in keep])
        mu, sd = Xf.mean(axis=1), Xf.std(axis=1)
        sd[sd == 0] = 1.0
        ym, ys = yf.mean(axis=1), yf.std(axis=1)
        ys[ys == 0] = 1.0
        Zf = (Xf - mu[:, None, :]) / sd[:, None, :]
        tf = (yf - ym[:, None]) / ys[:, None]
        Zo = (X - mu) / sd  # each fold's held-out sample, (n, p)
        sst = float(((y - y.mean()) ** 2).sum())
        self.validation_rmse_, self.validation_r2_, self.epochs_, best_epochs = {}, {}, {}, {}
        for h in sizes:
            mse, epoch = self._train_folds(Zf, tf, Zo, y, ym, ys, h)
            self.validation_rmse_[h] = float(np.sqrt(mse))
            self.validation_r2_[h] = 1.0 - n * mse / sst if sst > 0 else float("nan")
            self.epochs_[h] = epoch
            best_epochs[h] = epoch
        self.hidden_size_ = self._choose_size({h: v ** 2 for h, v in self.validation_rmse_.items()})
        self.x_mean_ = X.mean(axis=0)
        self.x_scale_ = X.std(axis=0)
        self.x_scale_[self.x_scale_ == 0] = 1.0
        self.y_mean_ = float(y.mean())
        self.y_scale_ = float(y.std()) or 1.0
        Z = (X - self.x_mean_) / self.x_scale_
        t = (y - self.y_mean_) / self.y_scale_
        self.best_epoch_ = best_epochs[self.hidden_size_]
        (self.W_, self.b_, self.v_, self.c_), _, _, _ = self._train(Z, t, Z, t, self.hidden_size_, epochs=self.best_epoch_)
        self.n_train_, self.n_validation_ = n, 1
        return self._finish(X, y, names)

    def _train_folds(self, Z, t, Zo, y, ym, ys, h):
        """Full-batch Adam on every fold at once (the same seeded start as _train) -> (mean held-out squared error in
        target units at the best epoch, that epoch); stops ``patience`` epochs after the best."""
        rng = np.random.default_rng([int(self.seed), h])
        f, m, p = Z.shape
        W0 = rng.normal(0.0, 1.0 / np.sqrt(p), (h, p))
        v0 = rng.normal(0.0, 1.0 / np.sqrt(h), h)
        params = [np.repeat(W0[None], f, 0), np.zeros((f, h)), np.repeat(v0[None], f, 0), np.zeros(f)]
        m1 = [np.zeros_like(a) for a in params]
        m2 = [np.zeros_like(a) for a in params]
        b1, b2, eps, lr = 0.9, 0.999, 1e-8, float(self.learning_rate)
        best = (np.inf, 0)
        for epoch in range(1, int(self.max_epochs) + 1):
            W, b, v, c = params
            H = np.tanh(np.einsum("fnp,fhp->fnh", Z, W) + b[:, None, :])
            e = np.einsum("fnh,fh->fn", H, v) + c[:, None] - t
            g_out = e / m
            gv = np.einsum("fnh,fn->fh", H, g_out)
            gc = g_out.sum(axis=1)
            gH = g_out[:, :, None] * v[:, None, :] * (1.0 - H**2)
            gW = np.einsum("fnh,fnp->fhp", gH, Z)
            gb = gH.sum(axis=1)
            for i, g in enumerate((gW, gb, gv, gc)):
                m1[i] = b1 * m1[i] + (1 - b1) * g
                m2[i] = b2 * m2[i] + (1 - b2) * g * g
                params[i] = params[i] - lr * (m1[i] / (1 - b1**epoch)) / (np.sqrt(m2[i] / (1 - b2**epoch)) + eps)
            W, b, v, c = params
            out = np.einsum("fh,fh->f", np.tanh(np.einsum("fp,fhp->fh", Zo, W) + b), v) + c
            mse = float(np.mean((ym + ys * out - y) ** 2))
            if mse < best[0] - 1e-15:
                best = (mse, epoch)
            elif epoch - best[1] >= int(self.patience):
                break
        return best

    def _train(self, Z, t, Zv, tv, h, epochs=None):
        """Full-batch Adam on back-propagated gradients with early stopping -> (params, best val RMSE, epochs, best epoch).
        ``epochs``: train exactly that many epochs and keep the last weights (no early stopping)."""
        rng = np.random.default_rng([int(self.seed), h])
        p = Z.shape[1]
        W = rng.normal(0.0, 1.0 / np.sqrt(p), (h, p))
        b = np.zeros(h)
        v = rng.normal(0.0, 1.0 / np.sqrt(h), h)
        c = 0.0
        params = [W, b, v, np.array(c)]
        m1 = [np.zeros_like(a, dtype=float) for a in params]
        m2 = [np.zeros_like(a, dtype=float) for a in params]
        b1, b2, eps, lr = 0.9, 0.999, 1e-8, float(self.learning_rate)
        n = Z.shape[0]
        best = (np.inf, [a.copy() for a in params], 0)
        epoch = 0
        for epoch in range(1, int(self.max_epochs if epochs is None else epochs) + 1):
            W, b, v, c = params
            H = np.tanh(Z @ W.T + b)
            e = H @ v + c - t  # (n,)
            # back-propagation of 0.5·mean(e²)
            g_out = e / n
            gv = H.T @ g_out
            gc = np.array(g_out.sum())
            gH = np.outer(g_out, v) * (1.0 - H**2)
            gW = gH.T @ Z
            gb = gH.sum(axis=0)
            for i, g in enumerate((gW, gb, gv, gc)):
                m1[i] = b1 * m1[i] + (1 - b1) * g
                m2[i] = b2 * m2[i] + (1 - b2) * g * g
                params[i] = params[i] - lr * (m1[i] / (1 - b1**epoch)) / (np.sqrt(m2[i] / (1 - b2**epoch)) + eps)
            W, b, v, c = params
            if epochs is not None:
                continue
            ev = np.tanh(Zv @ W.T + b) @ v + c - tv
            rv = float(np.sqrt(np.mean(ev**2)))
            if rv < best[0] - 1e-12:
                best = (rv, [a.copy() for a in params], epoch)
            elif epoch - best[2] >= int(self.patience):
                break
        if epochs is not None:
            W, b, v, c = params
            return (W, b, v, float(c)), None, epoch, epoch
        W, b, v, c = best[1]
        return (W, b, v, float(c)), best[0], epoch, best[2]

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = check_predict_x(self, X, "W_", lambda: self.W_.shape[1])
        Z = (X - self.x_mean_) / self.x_scale_
        return self.y_mean_ + self.y_scale_ * (np.tanh(Z @ self.W_.T + self.b_) @ self.v_ + self.c_)

    def statistics(self) -> dict[str, Any]:
        return {
            "n_samples": int(self.n_samples_),
            "n_train": self.n_train_,
            "n_validation": self.n_validation_,
            "validation": self.validation_,
            "r2": finite_or_none(self.rsquared_),
            "rmse": finite_or_none(self.rmse_),
            "hidden_size": int(self.hidden_size_),
            "validation_rmse_by_size": {str(k): finite_or_none(v) for k, v in self.validation_rmse_.items()},
            # Li 2021 Tables 18-19: MSE and R2 per hidden size (here on the validation samples)
            "validation_mse_by_size": {str(k): finite_or_none(v ** 2) for k, v in self.validation_rmse_.items()},
            "validation_r2_by_size": {str(k): finite_or_none(v) for k, v in self.validation_r2_.items()},
            "size_rule": self.size_rule if self.size_rule == "best" else "smallest_near_best (within %g of the lowest MSE)" % float(self.size_tolerance),
            "epochs_by_size": {str(k): int(v) for k, v in self.epochs_.items()},
            "best_epoch": int(self.best_epoch_),
            "weights": int(self.W_.size + self.b_.size + self.v_.size + 1),
            "seed": int(self.seed),
            # keys shared with the linear estimators' statistics, for the comparison tables
            "r2_adj": None, "F": None, "F_p": None, "residual_std_error": finite_or_none(self.rmse_),
        }

    def network(self) -> dict[str, Any]:
        """The fitted network as plain lists (the model document's ``thermal.network``)."""
        return {
            "activation": "tanh",
            "input_offset": [float(v) for v in self.x_mean_],
            "input_scale": [float(v) for v in self.x_scale_],
            "hidden_weights": [[float(v) for v in row] for row in self.W_],
            "hidden_bias": [float(v) for v in self.b_],
            "output_weights": [float(v) for v in self.v_],
            "output_bias": float(self.c_),
            "output_offset": float(self.y_mean_),
            "output_scale": float(self.y_scale_),
        }

    @classmethod
    def from_network(cls, net: dict[str, Any]) -> ANN:
        """An ANN predicting with the weights of a ``network()`` dict (no training data)."""
        self = cls()
        self.x_mean_ = np.asarray(net["input_offset"], dtype=float)
        self.x_scale_ = np.asarray(net["input_scale"], dtype=float)
        self.W_ = np.asarray(net["hidden_weights"], dtype=float).reshape(-1, self.x_mean_.size)
        self.b_ = np.asarray(net["hidden_bias"], dtype=float)
        self.v_ = np.asarray(net["output_weights"], dtype=float)
        self.c_ = float(net["output_bias"])
        self.y_mean_ = float(net["output_offset"])
        self.y_scale_ = float(net["output_scale"])
        self.hidden_size_ = self.b_.size
        return self
