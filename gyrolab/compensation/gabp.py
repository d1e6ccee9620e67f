"""GA-BP: a back-propagation network whose initial weights come from a genetic algorithm.

The network (paper §3.3.1, eqs 15–17) has ``n`` inputs, one hidden layer of ``l`` sigmoid
neurons and one linear output::

    g(x) = 1 / (1 + exp(-x))                                   (15)
    Y_h  = g( Σ_i W_ih X_i + a_h ),          h = 1 … l          (16)
    Z    = Σ_h Y_h W_h + b                                      (17)

and is trained to minimise the squared error E = ½ Σ_k (O_k − Z_k)² (eqs 18/19).

The weights are initialised by the GA of §3.3.2: every individual is the flat vector
``[W (n·l), a (l), W_out (l), b]``; fitness is the learning error of eq. 19 on the training
set; selection is *sort* (rank) selection — the population is sorted by error and the best
part survives as parents; crossover is the arithmetic (linear) crossover of eq. 20,
``c1 = m p1 + (1−m) p2``, ``c2 = m p2 + (1−m) p1`` with ``m ~ U(0, 1)``; mutation is
Michalewicz's non-uniform mutation (a step that shrinks as generations pass), plus the
paper's neuron mutation (a hidden neuron is deleted — its weights set to zero — or
re-added with fresh random weights). The best individual seeds back-propagation.

Back-propagation here is, by default, full-batch L-BFGS in torch (float64, strong-Wolfe
line search) on the same loss; ``BPConfig(optimizer="gd")`` is the paper's plain gradient
descent (fixed learning rate, fixed epochs). Why L-BFGS by default: the problem is tiny
(a few dozen weights, ~10⁴ samples, smooth loss) so a quasi-Newton method converges in
a few hundred iterations with no learning rate to tune, and full batch makes it
deterministic for a given seed. Inputs and output are standardised (zero mean, unit
standard deviation) before the GA and the training; the scalers are part of the model.

Units: inputs as given by the caller (the pipeline passes temperature in °C and, when
asked, dT/dt in °C/s); the output in the caller's unit (°/s for gyro drift).

Reference: J. Wei, Z. Zhang, H. Cao, X. Duan, "Hybrid temperature compensation model of
MEMS gyroscope based on GPSO-VMD and improved BP", Sensors and Materials 33 (2021) §3.3;
Z. Michalewicz, *Genetic Algorithms + Data Structures = Evolution Programs* (1996) §6
for non-uniform mutation.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from gyrolab.progress import progress


@dataclass(frozen=True)
class GAConfig:
    """GA settings (paper §3.3.2). ``bound`` limits every weight to ``[-bound, bound]``
    (standardised units); ``fitness_points`` caps the samples used for fitness (an even
    stride through the training set: the drift is slow, so fewer points see the same
    curve and keep the GA cheap)."""

    population: int = 40
    generations: int = 40
    parent_fraction: float = 0.5
    elite: int = 2
    crossover_prob: float = 0.8
    mutation_prob: float = 0.1
    nonuniform_b: float = 2.0
    neuron_mutation_prob: float = 0.05
    bound: float = 4.0
    fitness_points: int = 2000


#: Back-propagation optimisers: full-batch L-BFGS (default) or the paper's plain gradient
#: descent (§3.3.1: "use the gradient descent method to adjust the weights and threshold").
OPTIMIZERS = ("lbfgs", "gd")


@dataclass(frozen=True)
class BPConfig:
    """Back-propagation settings: hidden neurons, the optimiser and its budget.

    ``optimizer="lbfgs"``: at most ``max_iter`` L-BFGS iterations. ``optimizer="gd"``: the
    textbook BP step ``θ ← θ − η ∇E`` for ``epochs`` full-batch epochs at learning rate
    ``learning_rate`` (η). The paper prints neither η nor the epoch count; the defaults are
    those of the classic BP toolbox trainer (MATLAB ``traingd``: η = 0.01, 1000 epochs)."""

    hidden: int = 8
    max_iter: int = 400
    tolerance_grad: float = 1e-9
    tolerance_change: float = 1e-12
    optimizer: str = "lbfgs"
    learning_rate: float = 0.01
    epochs: int = 1000


def n_weights(n_in: int, hidden: int) -> int:
    """Length of the flat weight vector ``[W (n·l), a (l), W_out (l), b]``."""
    return n_in * hidden + hidden + hidden + 1


def unpack(theta: np.ndarray, n_in: int, hidden: int) -> tuple[np.ndarray, ...]:
    """Split flat weight vector(s) ``(..., D)`` into ``W (…, n, l), a (…, l), w (…, l), b (…)``."""
    i = n_in * hidden
    W = theta[..., :i].reshape(*theta.shape[:-1], n_in, hidden)
    a = theta[..., i : i + hidden]
    w = theta[..., i + hidden : i + 2 * hidden]
    b = theta[..., -1]
    return W, a, w, b


def forward(theta: np.ndarray, Xs: np.ndarray, n_in: int, hidden: int) -> np.ndarray:
    """Eqs 15–17 in numpy for one vector ``(D,)`` → ``(N,)`` or a population ``(P, D)`` →
    ``(P, N)``; ``Xs`` is the standardised input ``(N, n)``."""
    W, a, w, b = unpack(theta, n_in, hidden)
    z = np.einsum("ni,...ih->...nh", Xs, W) + a[..., None, :]
    Y = 0.5 * (1.0 + np.tanh(0.5 * z))  # = 1/(1+e^-z), overflow-free
    return np.einsum("...nh,...h->...n", Y, w) + b[..., None]


def _input_gradient(theta: np.ndarray, Xs: np.ndarray, n_in: int, hidden: int) -> np.ndarray:
    """∂Z/∂X (standardised units) of eqs 15–17: ``Σ_h W_ih w_h Y_h (1 − Y_h)``, ``(N, n)``.

    Row by row the same operations in the same order whatever N (the sums run over the
    hidden units one at a time): a reading evaluated alone gives the bits it gets inside
    a whole run (a BLAS product sums differently for different N)."""
    W, a, w, _ = unpack(theta, n_in, hidden)
    z = np.einsum("ni,ih->nh", Xs, W) + a
    Y = 0.5 * (1.0 + np.tanh(0.5 * z))
    d = Y * (1.0 - Y) * w
    g = np.zeros((Xs.shape[0], n_in))
    for h in range(hidden):
        g += d[:, h : h + 1] * W[:, h]
    return g


def _nonuniform(
    x: np.ndarray, gen: int, generations: int, lo: float, hi: float, b: float, rng
) -> np.ndarray:
    """Michalewicz non-uniform mutation of every element of ``x``:
    ``x + Δ(g, hi − x)`` or ``x − Δ(g, x − lo)`` (fair coin), ``Δ(g, y) = y (1 − r^{(1−g/G)^b})``.
    Early generations explore the whole range; late ones fine-tune."""
    r = rng.random(x.shape)
    frac = (1.0 - gen / max(generations, 1)) ** b
    up = rng.random(x.shape) >= 0.5
    delta_up = (hi - x) * (1.0 - r**frac)
    delta_dn = (x - lo) * (1.0 - r**frac)
    return np.where(up, x + delta_up, x - delta_dn)


@dataclass
class GAResult:
    """Best weight vector and the per-generation best / mean fitness (MSE, standardised)."""

    best: np.ndarray
    best_history: list[float] = field(default_factory=list)
    mean_history: list[float] = field(default_factory=list)


def genetic_init(
    Xs: np.ndarray,
    ys: np.ndarray,
    hidden: int,
    cfg: GAConfig = GAConfig(),
    seed: int = 0,
) -> GAResult:
    """Search initial weights by the GA of §3.3.2 on standardised data ``Xs (N, n)``,
    ``ys (N,)``. Fitness is the learning error of eq. 19 divided by N/2 (the MSE: same
    ordering, scale-free)."""
    rng = np.random.default_rng(seed)
    n_in = Xs.shape[1]
    D = n_weights(n_in, hidden)
    stride = max(1, int(np.ceil(len(ys) / cfg.fitness_points)))
    Xf, yf = Xs[::stride], ys[::stride]
    P, B = cfg.population, cfg.bound
    pop = rng.uniform(-B, B, size=(P, D))
    n_par = max(2, int(round(cfg.parent_fraction * P)))
    res = GAResult(best=pop[0])

    def fitness(pop: np.ndarray) -> np.ndarray:
        err = forward(pop, Xf, n_in, hidden) - yf[None, :]
        return np.mean(err * err, axis=1)

    fit = fitness(pop)
    bar = progress(cfg.generations, desc="GA init (GA-BP)", unit="gen")
    try:
        for gen in range(cfg.generations):
            order = np.argsort(fit, kind="stable")  # sort selection: rank by error
            pop, fit = pop[order], fit[order]
            res.best_history.append(float(fit[0]))
            res.mean_history.append(float(np.mean(fit)))
            parents = pop[:n_par]
            children = [pop[: cfg.elite].copy()]
            n_need = P - cfg.elite
            while sum(len(c) for c in children) - cfg.elite < n_need:
                i, j = rng.choice(n_par, size=2, replace=False)
                p1, p2 = parents[i], parents[j]
                if rng.random() < cfg.crossover_prob:
                    m = rng.random()  # eq. 20, one m per pair
                    c1, c2 = m * p1 + (1 - m) * p2, m * p2 + (1 - m) * p1
                else:
                    c1, c2 = p1.copy(), p2.copy()
                kids = np.stack([c1, c2])
                mask = rng.random(kids.shape) < cfg.mutation_prob
                mutated = _nonuniform(kids, gen, cfg.generations, -B, B, cfg.nonuniform_b, rng)
                kids = np.where(mask, mutated, kids)
                for k in range(2):
                    if rng.random() < cfg.neuron_mutation_prob:
                        _neuron_mutation(kids[k], n_in, hidden, B, rng)
                children.append(kids)
            pop = np.concatenate(children)[:P]
            fit = np.concatenate([fit[: cfg.elite], fitness(pop[cfg.elite :])])
            bar.update(1)
            bar.set_postfix(mse=f"{fit.min():.3g}")
    finally:
        bar.close()
    k = int(np.argmin(fit))
    res.best = pop[k].copy()
    res.best_history.append(float(fit[k]))
    res.mean_history.append(float(np.mean(fit)))
    return res


def _neuron_mutation(theta: np.ndarray, n_in: int, hidden: int, bound: float, rng) -> None:
    """The paper's structural mutation, in place: delete a hidden neuron (its weights set to
    zero) or add one (its weights drawn afresh), each with probability ½."""
    h = int(rng.integers(hidden))
    idx = [i * hidden + h for i in range(n_in)]
    idx += [n_in * hidden + h, n_in * hidden + hidden + h]
    if rng.random() < 0.5:
        theta[idx] = 0.0
    else:
        theta[idx] = rng.uniform(-bound, bound, size=len(idx))


def gd_train(
    theta0: np.ndarray, Xs: np.ndarray, ys: np.ndarray, hidden: int, cfg: BPConfig
) -> tuple[np.ndarray, list[float]]:
    """Plain full-batch gradient-descent BP (paper §3.3.1): ``θ ← θ − η ∂E/∂θ`` on
    E = ½ Σ (O − Z)² / N (eqs 18/19, mean form, so η does not scale with N), with the
    gradients of eqs 15–17 by the chain rule (back-propagation):

        δ = Z − O,  ∂E/∂b = mean δ,  ∂E/∂W_h = mean δ Y_h,
        ∂E/∂a_h = mean δ W_h Y_h (1 − Y_h),  ∂E/∂W_ih = mean δ W_h Y_h (1 − Y_h) X_i.

    Returns the trained flat vector and the loss before each epoch plus the final one."""
    n_in = Xs.shape[1]
    th = np.array(theta0, dtype=float)
    i = n_in * hidden
    n = ys.size
    eta = float(cfg.learning_rate)
    losses: list[float] = []
    for _ in range(int(cfg.epochs)):
        W = th[:i].reshape(n_in, hidden)
        a, w = th[i : i + hidden], th[i + hidden : i + 2 * hidden]
        # a diverging descent overflows before the check below stops it: no warnings then
        with np.errstate(over="ignore", invalid="ignore"):
            Y = 0.5 * (1.0 + np.tanh(0.5 * (Xs @ W + a)))
            d = Y @ w + th[-1] - ys
            losses.append(0.5 * float(d @ d) / n)
            gh = (d[:, None] * (Y * (1.0 - Y))) * w  # (N, l): δ back-propagated to the hidden
            grad = np.concatenate(
                [(Xs.T @ gh).ravel() / n, gh.mean(axis=0), (Y.T @ d) / n, [d.mean()]]
            )
            th -= eta * grad
        if not np.all(np.isfinite(th)):
            raise ValueError(f"gradient descent diverged (learning rate {eta} too large)")
    z = forward(th, Xs, n_in, hidden) - ys
    losses.append(0.5 * float(z @ z) / n)
    return th, losses


def _bp_train(
    theta0: np.ndarray, Xs: np.ndarray, ys: np.ndarray, hidden: int, cfg: BPConfig
) -> tuple[np.ndarray, list[float]]:
    """Train from ``theta0`` with ``cfg.optimizer``: full-batch L-BFGS on
    E = ½ Σ (O − Z)² / N (eqs 18/19, mean form), or plain gradient descent
    (:func:`gd_train`). Returns the trained flat vector and the loss history (after each
    L-BFGS function evaluation / each GD epoch)."""
    if cfg.optimizer == "gd":
        return gd_train(theta0, Xs, ys, hidden, cfg)
    if cfg.optimizer != "lbfgs":
        raise ValueError(f"BP optimizer must be one of {OPTIMIZERS}, not {cfg.optimizer!r}")
    import torch

    n_in = Xs.shape[1]
    X = torch.as_tensor(Xs, dtype=torch.float64)
    y = torch.as_tensor(ys, dtype=torch.float64)
    theta = torch.tensor(theta0, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS(
        [theta],
        lr=1.0,
        max_iter=cfg.max_iter,
        tolerance_grad=cfg.tolerance_grad,
        tolerance_change=cfg.tolerance_change,
        history_size=20,
        line_search_fn="strong_wolfe",
    )
    losses: list[float] = []

    def closure() -> torch.Tensor:
        opt.zero_grad()
        i = n_in * hidden
        W = theta[:i].reshape(n_in, hidden)
        a = theta[i : i + hidden]
        w = theta[i + hidden : i + 2 * hidden]
        Z = torch.sigmoid(X @ W + a) @ w + theta[-1]
        loss = 0.5 * torch.mean((y - Z) ** 2)
        loss.backward()
        losses.append(float(loss.detach()))
        return loss

    # a few dozen weights: one thread is fastest, and threads fighting over a busy
    # machine made this 5x slower in measurement
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        opt.step(closure)
    finally:
        torch.set_num_threads(threads)
    return theta.detach().numpy().copy(), losses


@dataclass
class MLPDriftModel:
    """A trained eq. 15–17 network with its input/output scalers.

    ``predict(X)`` takes raw inputs ``(N, n)`` (the units of the training inputs) and
    returns the drift in the training target's unit."""

    theta: np.ndarray
    n_in: int
    hidden: int
    x_mean: np.ndarray
    x_std: np.ndarray
    y_mean: float
    y_std: float
    init: str = "ga"
    x_min: np.ndarray | None = None
    x_max: np.ndarray | None = None
    ga_best_history: list[float] = field(default_factory=list)
    ga_mean_history: list[float] = field(default_factory=list)
    bp_loss_history: list[float] = field(default_factory=list)
    config: dict[str, Any] = field(default_factory=dict)

    def predict(self, X: np.ndarray, chunk: int = 1 << 18) -> np.ndarray:
        """Drift at inputs ``X (N, n)``.

        Inside the training range this is the network (eqs 15–17). Outside it (``x_min`` /
        ``x_max``, per input) the network is continued *linearly*: the inputs are clipped
        to the range and the first-order Taylor term at the clipped point is added,
        ``f(x) ≈ f(x_c) + ∇f(x_c)·(x − x_c)``. A sigmoid network's own extrapolation is
        arbitrary (it follows whatever sigmoid edge the training left there); a linear
        continuation is the usual rule for calibration tables."""
        X = np.asarray(X, dtype=float)
        X = X[:, None] if X.ndim == 1 else X
        if X.shape[1] != self.n_in:
            raise ValueError(f"expected {self.n_in} input column(s), got {X.shape[1]}")
        out = np.empty(X.shape[0])
        have_range = self.x_min is not None and self.x_max is not None
        for s in range(0, X.shape[0], chunk):  # bounded memory on long runs
            Xr = X[s : s + chunk]
            Xc = np.clip(Xr, self.x_min, self.x_max) if have_range else Xr
            Xs = (Xc - self.x_mean) / self.x_std
            y = forward(self.theta, Xs, self.n_in, self.hidden)
            if have_range:
                dx = (Xr - Xc) / self.x_std
                out_of = np.any(dx != 0, axis=1)
                if out_of.any():
                    g = _input_gradient(self.theta, Xs[out_of], self.n_in, self.hidden)
                    y[out_of] += np.sum(g * dx[out_of], axis=1)
            out[s : s + chunk] = y
        return out * self.y_std + self.y_mean

    def spec(self, inputs: list[str], window_s: float | None) -> dict[str, Any]:
        """The exported form (``mlp``, :mod:`gyrolab.compensation.regressors`) on inputs
        named ``inputs``; ``window_s``: the dT/dt window when an input is dT/dt."""
        W, a, w, b = unpack(np.asarray(self.theta, dtype=float), self.n_in, self.hidden)
        if self.x_min is None or self.x_max is None:
            raise ValueError("network without a calibrated input range: refit the model")
        return {
            "kind": "mlp",
            "init": self.init,
            "inputs": list(inputs),
            "dtdt_window_s": window_s,
            "hidden": int(self.hidden),
            "x_mean": np.asarray(self.x_mean, dtype=float).tolist(),
            "x_std": np.asarray(self.x_std, dtype=float).tolist(),
            "x_min": np.asarray(self.x_min, dtype=float).tolist(),
            "x_max": np.asarray(self.x_max, dtype=float).tolist(),
            "W": W.tolist(),
            "a": a.tolist(),
            "w": w.tolist(),
            "b": float(b),
            "y_mean": float(self.y_mean),
            "y_std": float(self.y_std),
        }

    def torch_state_dict(self) -> dict[str, Any]:
        """The weights as a ``torch.nn.Sequential(Linear(n, l), Sigmoid(), Linear(l, 1))``
        state dict on *standardised* inputs/outputs (see ``x_mean``/``y_mean``)."""
        import torch

        W, a, w, b = unpack(self.theta, self.n_in, self.hidden)
        return {
            "0.weight": torch.tensor(W.T.copy()),
            "0.bias": torch.tensor(a.copy()),
            "2.weight": torch.tensor(w[None, :].copy()),
            "2.bias": torch.tensor(np.array([b])),
        }

    # -- persistence: plain arrays + JSON-able metadata (no pickled code)
    def to_state(self, prefix: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        meta = {
            "kind": "mlp",
            "init": self.init,
            "n_in": self.n_in,
            "hidden": self.hidden,
            "y_mean": self.y_mean,
            "y_std": self.y_std,
            "config": self.config,
        }
        arrays = {
            f"{prefix}theta": self.theta,
            f"{prefix}x_mean": self.x_mean,
            f"{prefix}x_std": self.x_std,
            f"{prefix}x_min": np.asarray([] if self.x_min is None else self.x_min, dtype=float),
            f"{prefix}x_max": np.asarray([] if self.x_max is None else self.x_max, dtype=float),
            f"{prefix}ga_best_history": np.asarray(self.ga_best_history, dtype=float),
            f"{prefix}ga_mean_history": np.asarray(self.ga_mean_history, dtype=float),
            f"{prefix}bp_loss_history": np.asarray(self.bp_loss_history, dtype=float),
        }
        return meta, arrays

    @classmethod
    def from_state(
        cls, meta: dict[str, Any], arrays: dict[str, np.ndarray], prefix: str
    ) -> MLPDriftModel:
        return cls(
            theta=np.asarray(arrays[f"{prefix}theta"], dtype=float),
            n_in=int(meta["n_in"]),
            hidden=int(meta["hidden"]),
            x_mean=np.asarray(arrays[f"{prefix}x_mean"], dtype=float),
            x_std=np.asarray(arrays[f"{prefix}x_std"], dtype=float),
            y_mean=float(meta["y_mean"]),
            y_std=float(meta["y_std"]),
            init=str(meta.get("init", "ga")),
            x_min=_opt(arrays.get(f"{prefix}x_min")),
            x_max=_opt(arrays.get(f"{prefix}x_max")),
            ga_best_history=list(arrays.get(f"{prefix}ga_best_history", [])),
            ga_mean_history=list(arrays.get(f"{prefix}ga_mean_history", [])),
            bp_loss_history=list(arrays.get(f"{prefix}bp_loss_history", [])),
            config=dict(meta.get("config", {})),
        )


def _opt(a: np.ndarray | None) -> np.ndarray | None:
    return None if a is None or np.size(a) == 0 else np.asarray(a, dtype=float)


def _standardise(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, ...]:
    X = np.asarray(X, dtype=float)
    if X.ndim == 1:
        X = X[:, None]
    y = np.asarray(y, dtype=float).ravel()
    if X.shape[0] != y.size:
        raise ValueError(f"X has {X.shape[0]} rows but y has {y.size}")
    if X.shape[0] < 4 or not (np.all(np.isfinite(X)) and np.all(np.isfinite(y))):
        raise ValueError("need at least 4 finite samples")
    xm, xs = X.mean(axis=0), X.std(axis=0)
    xs = np.where(xs > 0, xs, 1.0)  # a constant input carries no information: keep it at 0
    ym, ys_ = float(y.mean()), float(y.std())
    ys_ = ys_ if ys_ > 0 else 1.0
    return X, y, xm, xs, ym, ys_


def fit_mlp(
    X: np.ndarray,
    y: np.ndarray,
    *,
    init: str = "ga",
    bp: BPConfig = BPConfig(),
    ga: GAConfig = GAConfig(),
    seed: int = 0,
) -> MLPDriftModel:
    """Fit the eq. 15–17 network to ``y ≈ f(X)``.

    ``init="ga"`` is GA-BP (initial weights by :func:`genetic_init`); ``init="random"`` is
    plain BP: the same network and the same training from Xavier-uniform random weights
    (zero biases) — the baseline that shows what the GA buys."""
    import torch

    X, y, xm, xs, ym, ys_ = _standardise(X, y)
    Xs, yz = (X - xm) / xs, (y - ym) / ys_
    n_in, hidden = X.shape[1], bp.hidden
    torch.manual_seed(seed)
    ga_best: list[float] = []
    ga_mean: list[float] = []
    if init == "ga":
        res = genetic_init(Xs, yz, hidden, ga, seed=seed)
        theta0 = res.best
        ga_best, ga_mean = res.best_history, res.mean_history
    elif init == "random":
        rng = np.random.default_rng(seed)
        lim1 = np.sqrt(6.0 / (n_in + hidden))
        lim2 = np.sqrt(6.0 / (hidden + 1))
        theta0 = np.concatenate(
            [
                rng.uniform(-lim1, lim1, n_in * hidden),
                np.zeros(hidden),
                rng.uniform(-lim2, lim2, hidden),
                [0.0],
            ]
        )
    else:
        raise ValueError(f"init must be 'ga' or 'random', not {init!r}")
    theta, losses = _bp_train(theta0, Xs, yz, hidden, bp)
    opt = "lbfgs-strong-wolfe" if bp.optimizer == "lbfgs" else "gradient-descent"
    cfg: dict[str, Any] = {"bp": asdict(bp), "optimizer": opt, "seed": seed}
    if init == "ga":
        cfg["ga"] = asdict(ga)
    return MLPDriftModel(
        theta=theta,
        n_in=n_in,
        hidden=hidden,
        x_mean=xm,
        x_std=xs,
        y_mean=ym,
        y_std=ys_,
        init=init,
        x_min=X.min(axis=0),
        x_max=X.max(axis=0),
        ga_best_history=ga_best,
        ga_mean_history=ga_mean,
        bp_loss_history=losses,
        config=cfg,
    )


def fit_gabp(X: np.ndarray, y: np.ndarray, **kw: Any) -> MLPDriftModel:
    """GA-BP (paper §3.3.2): :func:`fit_mlp` with GA-chosen initial weights."""
    return fit_mlp(X, y, init="ga", **kw)
