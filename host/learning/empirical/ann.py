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
* for every hidden size in ``hidden_sizes`` (3..7 as in the paper) the network
  is trained from a seeded initialisation, stopping when the validation RMSE has
  not improved for ``patience`` epochs (at most ``max_epochs``); the weights of
  the best validation epoch are kept;
* the hidden size with the lowest validation RMSE wins (ties: fewer nodes).

The kept network is the one trained on the training part only (early stopping
needs the validation part untouched); ``statistics()`` reports the fit on all
training data, the validation RMSE of every size and the epochs used.
"""
import numpy as np

from host.learning.empirical import EmpiricalDataError
from host.learning.empirical.checks import check_predict_x, check_xy, finite_or_none


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

    def __init__(self, *, hidden_sizes=(3, 4, 5, 6, 7), validation="random", validation_fraction=0.2, max_epochs=3000, patience=200,
                 learning_rate=0.01, seed=0, fit_intercept=True):
        self.hidden_sizes = hidden_sizes
        self.validation = validation
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
        return [int(h) for h in sizes]

    def fit(self, X, y, names=None, groups=None):
        sizes = self._check()
        X, y, names = check_xy(X, y, names, None, "ANN")
        n, p = X.shape
        val = np.zeros(n, bool)
        if self.validation not in ("random", "last_group"):
            raise EmpiricalDataError("ann: validation must be 'random' or 'last_group', got %r" % (self.validation,))
        if self.validation == "last_group":
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
        self.validation_rmse_, self.epochs_, best = {}, {}, None
        for h in sizes:
            params, rmse, epochs, best_epoch = self._train(Z[tr], t[tr], Z[val], t[val], h)
            self.validation_rmse_[h] = rmse * self.y_scale_
            self.epochs_[h] = epochs
            if best is None or rmse < best[1]:
                best = (h, rmse, params, best_epoch)
        self.hidden_size_, _, (self.W_, self.b_, self.v_, self.c_), self.best_epoch_ = best
        self.names_ = names
        self.n_samples_ = n
        self.n_train_, self.n_validation_ = int(tr.sum()), int(val.sum())
        r = y - self.predict(X)
        self.rmse_ = float(np.sqrt(np.mean(r**2)))
        sst = float(((y - y.mean()) ** 2).sum())
        self.rsquared_ = 1.0 - float(r @ r) / sst if sst > 0 else float("nan")
        return self

    def _train(self, Z, t, Zv, tv, h):
        """Full-batch Adam on back-propagated gradients with early stopping -> (params, best val RMSE, epochs, best epoch)."""
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
        for epoch in range(1, int(self.max_epochs) + 1):
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
            ev = np.tanh(Zv @ W.T + b) @ v + c - tv
            rv = float(np.sqrt(np.mean(ev**2)))
            if rv < best[0] - 1e-12:
                best = (rv, [a.copy() for a in params], epoch)
            elif epoch - best[2] >= int(self.patience):
                break
        W, b, v, c = best[1]
        return (W, b, v, float(c)), best[0], epoch, best[2]

    def predict(self, X):
        X = check_predict_x(self, X, "W_", lambda: self.W_.shape[1])
        Z = (X - self.x_mean_) / self.x_scale_
        return self.y_mean_ + self.y_scale_ * (np.tanh(Z @ self.W_.T + self.b_) @ self.v_ + self.c_)

    def statistics(self):
        return {
            "n_samples": int(self.n_samples_),
            "n_train": self.n_train_,
            "n_validation": self.n_validation_,
            "validation": self.validation_,
            "r2": finite_or_none(self.rsquared_),
            "rmse": finite_or_none(self.rmse_),
            "hidden_size": int(self.hidden_size_),
            "validation_rmse_by_size": {str(k): finite_or_none(v) for k, v in self.validation_rmse_.items()},
            "epochs_by_size": {str(k): int(v) for k, v in self.epochs_.items()},
            "best_epoch": int(self.best_epoch_),
            "weights": int(self.W_.size + self.b_.size + self.v_.size + 1),
            "seed": int(self.seed),
            # keys shared with the linear estimators' statistics, for the comparison tables
            "r2_adj": None, "F": None, "F_p": None, "residual_std_error": finite_or_none(self.rmse_),
        }

    def network(self):
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
    def from_network(cls, net):
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
