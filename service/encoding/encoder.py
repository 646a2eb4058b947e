"""The phase encoder: k digit classifiers whose digits decode into a frame index."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from service.encoding import appending, encoder_storage
from service.encoding.base import Localization, PlaceRecognizer
from service.encoding.conditions import fitted_conditions
from service.encoding.decoding import DECODE_MODES, decode
from service.encoding.digit_classifier import DigitClassifier
from service.encoding.footprint import Footprint
from service.encoding.front_end import FrontEnd
from service.encoding.inverted_file import InvertedFile, Search, check_search, uses_ivf
from service.encoding.patterns import n_selected
from service.encoding.phases import auto_periods, index_to_labels, validate_periods
from service.encoding.progress import ProgressFn, Steps
from service.encoding.prototype import DEFAULT_TEMPERATURE
from service.encoding.quantization import check_dtype
from service.encoding.residue import CODES, residue_periods, validate_residue_periods
from service.encoding.serving_plan import plan_for
from service.encoding.streamed_fit import fit_class_prototypes, fit_frame_prototypes
from service.encoding.projection_width import choose_width
from service.encoding.trainers import TRAINERS
from service.encoding.traversals import as_traversals, per_place_C
from service.errors import InvalidParameterError


class PhaseEncoder(PlaceRecognizer):
    """Sub-linear place encoder (Le & Milford 2018) for one route segment.

    Parameters
    ----------
    n_patterns : number of phase encoders k (ignored when ``periods`` is given).
    periods : explicit periods τ1…τk (τ1 most significant); ``None`` picks balanced periods.
    rho : fraction of descriptor columns each encoder keeps, ``d' = round(ρ·d)``.
    gamma : L1 bound of the pattern weights; ``None`` uses ``√d'``.
    trainer : ``logreg`` | ``svm`` | ``ridge`` | ``torch``.
    C : inverse regularisation strength of the trainers (paper code: 4).
    decode : ``joint`` (best valid index) or ``argmax`` (paper: each digit on its own, and
        jointly when that index is off the route). ``localize`` decodes exactly
        (:mod:`service.encoding.serving_plan`), where the two coincide.
    beam_width : beams per digit of the reference beam-search decoder
        (:func:`service.encoding.decoding.reference_localize`).
    dtype : storage dtype of the weights: float64, float32, float16 or int8.
    normalize : z-score columns with the training statistics (stored in the model).
    random_state : seed for the trainers that use one.
    n_jobs : threads solving the one-vs-rest problems of ``logreg``/``svm`` (-1 = all cores).
    code : ``mixed_radix`` (the paper's digits) or ``residue`` (``i mod τ_j``,
        :mod:`service.encoding.residue`).
    code_ratio, code_exponent : ``Στ ≈ code_ratio·N^code_exponent`` of automatic residue
        periods (an exponent below 1: a code that grows sub-linearly with the route).
    n_components : PCA components of the projection front-end (``None``: no projection,
        :mod:`service.encoding.projection`).
    whiten_power : whitening of the projection (component ``c`` divided by ``√λ_c^power``).
    temperature : scores are divided by it before the log-softmax (``None``: the trainer's
        default, :data:`service.encoding.prototype.DEFAULT_TEMPERATURE` for ``prototype``,
        else 1); :func:`service.encoding.calibration.calibrate` fits it on held-out queries.
    auto_width : choose the projection width from the route: at most ``n_components``, at
        most 0.7 of the training rows, and the model within ``N·d`` bytes, exact NN on the
        route's uint8 rows (:mod:`service.encoding.projection_width`).
    search : how a model with one class per frame (``k = 1``) answers: ``flat`` scans every
        frame (exact), ``ivf`` through an inverted file of its prototypes, ``auto`` the
        inverted file on long routes (:mod:`service.encoding.inverted_file`).
    nlist, nprobe : lists of the inverted file and lists scanned per query (``None``: ≈ 4√N
        and 20 of them, or as many as hold 4,096 prototypes on average where 20 hold fewer).

    The constructor's defaults are the paper's algorithm, so the parameters recorded in older
    artifacts keep their meaning; the product default is the ``robust`` preset
    (:mod:`service.encoding.presets`, :class:`service.encoding.factory.ModelParams`).
    """

    kind = "phase_encoder"

    def __init__(
        self,
        n_patterns: int = 2,
        periods: Sequence[int] | None = None,
        rho: float = 0.5,
        gamma: float | None = None,
        trainer: str = "logreg",
        C: float = 4.0,
        decode: str = "joint",
        beam_width: int = 64,
        dtype: str = "float32",
        normalize: bool = True,
        random_state: int | None = 0,
        n_jobs: int = 1,
        code: str = "mixed_radix",
        code_ratio: float = 1.0,
        code_exponent: float = 1.0,
        n_components: int | None = None,
        whiten_power: float = 0.75,
        temperature: float | None = None,
        auto_width: bool = False,
        search: str = "auto",
        nlist: int | None = None,
        nprobe: int | None = None,
    ) -> None:
        self.n_patterns = n_patterns
        self.periods = periods
        self.rho = rho
        self.gamma = gamma
        self.trainer = trainer
        self.C = C
        self.decode = decode
        self.beam_width = beam_width
        self.dtype = dtype
        self.normalize = normalize
        self.random_state = random_state
        self.n_jobs = n_jobs
        self.code = code
        self.code_ratio = code_ratio
        self.code_exponent = code_exponent
        self.n_components = n_components
        self.whiten_power = whiten_power
        self.temperature = temperature
        self.auto_width = auto_width
        self.search = search
        self.nlist = nlist
        self.nprobe = nprobe

    # -- fitting ------------------------------------------------------------------------
    def _validate_params(self, n_features: int) -> None:
        if self.trainer not in TRAINERS:
            raise InvalidParameterError(
                f"unknown trainer {self.trainer!r}; choose one of {TRAINERS}"
            )
        if self.decode not in DECODE_MODES:
            raise InvalidParameterError(
                f"unknown decode mode {self.decode!r}; choose one of {DECODE_MODES}"
            )
        check_dtype(self.dtype)
        check_search(self.search)
        for name in ("nlist", "nprobe"):
            value = getattr(self, name)
            if value is not None and int(value) < 1:
                raise InvalidParameterError(f"{name} must be >= 1, got {value}")
        if self.code not in CODES:
            raise InvalidParameterError(f"unknown code {self.code!r}; choose one of {CODES}")
        if not self.code_ratio > 0:
            raise InvalidParameterError(f"code_ratio must be > 0, got {self.code_ratio}")
        if not 0.0 < self.code_exponent <= 1.0:
            raise InvalidParameterError(
                f"code_exponent must be in (0, 1], got {self.code_exponent}"
            )
        if self.n_components is not None and int(self.n_components) < 1:
            raise InvalidParameterError(f"n_components must be >= 1, got {self.n_components}")
        if not 0.0 <= self.whiten_power <= 1.0:
            raise InvalidParameterError(f"whiten_power must lie in [0, 1], got {self.whiten_power}")
        if self.temperature is not None and not 0 < self.temperature < float("inf"):
            raise InvalidParameterError(f"temperature must be > 0, got {self.temperature}")
        n_selected(n_features, self.rho)  # raises on rho outside (0, 1]
        if self.gamma is not None and not self.gamma >= 1:
            raise InvalidParameterError(f"gamma must be >= 1, got {self.gamma}")
        if int(self.beam_width) < 1:
            raise InvalidParameterError(f"beam_width must be >= 1, got {self.beam_width}")
        if not self.C > 0:
            raise InvalidParameterError(f"C must be > 0, got {self.C}")

    def fit(
        self, X: Any, y: Any = None, progress: ProgressFn | None = None, *, places: Any = None,
        conditions: Sequence[str | None] | None = None,
    ) -> PhaseEncoder:
        """Learn the encoders from descriptors whose rows are frames in route order, or from
        several traversals of the route, frame-aligned or with ``places`` giving each row's
        place (:mod:`service.encoding.traversals`). ``conditions``: one condition key (or
        ``None``) per traversal, whose statistics queries may name
        (:mod:`service.encoding.conditions`).

        ``progress(detail, done, total)`` follows the classes of every digit
        (:mod:`service.encoding.progress`)."""
        del y  # the labels are the places (the row order of one traversal)
        tr = as_traversals(X, places, keep_dtype=True)  # float32 rows stay float32 (a map)
        given, X = X, tr.rows
        self._validate_params(X.shape[1])
        width = self._front_width(tr.n_places, X.shape[0], X.shape[1])
        front = FrontEnd.fit(X, bool(self.normalize), width, float(self.whiten_power), self.dtype)
        if self._one_prototype_per_row(tr.places, tr.n_traversals, X.shape[0]):
            fit_frame_prototypes(self, X, front, progress)
        elif self._class_prototypes(tr.places, tr.n_traversals, X.shape[0]):
            fit_class_prototypes(self, X, front, progress)
        else:
            self._fit_normalised(front.transform(X), progress, tr.places, tr.n_traversals)
        self.normalizer_ = front if front.normalizer or front.projection else None
        self.ivf_ = self._fit_inverted_file()
        self.conditions_ = fitted_conditions(given, conditions)
        self._set_fitted(self.n_frames_, X.shape[1], tr.n_traversals)
        return self

    def _one_prototype_per_row(self, places: np.ndarray | None, n_traversals: int,
                               n_rows: int) -> bool:  # fmt: skip
        """One traversal, ``prototype`` classes of one frame each, every column kept: the
        class means are the rows themselves, fitted in row blocks."""
        return (places is None and n_traversals == 1 and self.trainer == "prototype"
                and len(self.periods_for(n_rows)) == 1 and float(self.rho) == 1.0)  # fmt: skip

    def _class_prototypes(self, places: np.ndarray | None, n_traversals: int,
                          n_rows: int) -> bool:  # fmt: skip
        """One traversal, ``prototype`` classes of a residue code, every class with rows:
        the class sums are accumulated in row blocks of the route."""
        return (places is None and n_traversals == 1 and self.trainer == "prototype"
                and self.code == "residue" and max(self.periods_for(n_rows)) <= n_rows)  # fmt: skip

    def _fit_inverted_file(self) -> InvertedFile | None:
        """The inverted file of a one-class-per-frame model whose ``search`` asks for one."""
        if len(self.digits_) != 1 or not uses_ivf(self.search, self.n_frames_):
            return None
        lin = self.digits_[0].linear
        nlist = None if self.nlist is None else min(int(self.nlist), self.n_frames_)
        return InvertedFile.fit(lin.weight, lin.scale, nlist, self.nprobe,
                                seed=int(self.random_state or 0))  # fmt: skip

    def _front_width(self, n_places: int, n_rows: int, n_features: int) -> int | None:
        """The projection width to fit: ``n_components``, or chosen by ``auto_width``."""
        if self.n_components is None or not self.auto_width:
            return self.n_components
        return choose_width(int(self.n_components), n_places, n_rows, n_features,
                            self.periods_for(n_places), self.dtype).width  # fmt: skip

    def periods_for(self, n_frames: int) -> tuple[int, ...]:
        """The periods a fit on ``n_frames`` frames uses (its progress counts their sum)."""
        if self.code == "residue":
            if self.periods is not None:
                return validate_residue_periods(self.periods, n_frames)
            return residue_periods(n_frames, int(self.n_patterns), float(self.code_ratio),
                                   float(self.code_exponent))  # fmt: skip
        if self.periods is not None:
            return validate_periods(self.periods, n_frames)
        return auto_periods(n_frames, int(self.n_patterns))

    def frame_labels_(self) -> np.ndarray:
        """``(N, k)`` digit labels of every frame of the fitted route."""
        self._check_fitted()
        return _labels(self.code, np.arange(self.n_frames_), self.periods_)

    def _temperature(self) -> float:
        if self.temperature is not None:
            return float(self.temperature)
        return DEFAULT_TEMPERATURE if self.trainer == "prototype" else 1.0

    def _fit_normalised(
        self,
        Xn: np.ndarray,
        progress: ProgressFn | None = None,
        places: np.ndarray | None = None,
        n_traversals: int = 1,
    ) -> PhaseEncoder:
        """Fit on rows that went through the front-end; ``places`` (validated, every place
        0…N−1 present) gives each row's place, ``None`` means row i is place i."""
        d = Xn.shape[1]
        n = Xn.shape[0] if places is None else int(places.max()) + 1
        self._validate_params(d)
        self.periods_ = self.periods_for(n)
        labels = _labels(self.code, np.arange(n) if places is None else places, self.periods_)
        C = per_place_C(self.C, n, Xn.shape[0])
        k = len(self.periods_)
        steps = Steps(progress, [f"digit {j + 1}/{k}" for j in range(k)], self.periods_)
        self.digits_ = []
        for j, tau in enumerate(self.periods_):
            self.digits_.append(DigitClassifier.fit(
                Xn,
                labels[:, j],
                tau,
                rho=self.rho,
                gamma=self.gamma,
                trainer=self.trainer,
                C=C,
                dtype=self.dtype,
                random_state=self.random_state,
                n_jobs=self.n_jobs,
                progress=steps.step(j),
                temperature=self._temperature(),
            ))  # fmt: skip
            steps.done(j)
        self.tallies_ = appending.tallies_of(self, Xn, labels)
        self.whitening_: appending.ConditionWhitening | None = None
        self.normalizer_ = None  # fit() sets the front-end; a chunk's encoder has none
        self._set_fitted(n, d, n_traversals)
        return self

    def partial_fit(
        self, X: Any, y: Any = None, *, places: Any = None, extend: bool = False,
        whiten: bool | None = None, condition: str | None = None,
    ) -> PhaseEncoder:  # fmt: skip
        """Append one traversal (an array) or several (a list, with a place index each) to
        the fitted model, in time proportional to the new rows: class means updated, the
        column statistics and PCA axes kept (:mod:`service.encoding.appending`). ``places``:
        each row's place (``None``: row ``i`` is place ``i``); ``extend``: places beyond the
        route extend it; ``whiten``: learn the new rows' within-place scatter (default: where
        the model has one class per place); ``condition``: the traversals' condition key
        (``season=winter``), whose statistics are recorded for queries to name."""
        del y
        self._check_fitted()
        appending.append(self, X, places, extend, whiten, condition)
        return self

    @property
    def pattern_weights_(self) -> list[np.ndarray]:
        """Sparse column weights of each encoder (available after ``fit``, not after load)."""
        self._check_fitted()
        return [dc.pattern.weights for dc in self.digits_ if dc.pattern is not None]

    @property
    def selected_columns_(self) -> list[np.ndarray]:
        self._check_fitted()
        return [dc.columns for dc in self.digits_]

    # -- querying -----------------------------------------------------------------------
    def _transform(self, Q: np.ndarray) -> np.ndarray:
        return self.normalizer_.transform(Q) if self.normalizer_ is not None else Q

    def _decode_normalised(self, Qn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference decode of queries that went through the front-end (indices, scores):
        beam search over mixed-radix digits, every frame's labels for a residue code."""
        logps = [dc.log_probs(Qn) for dc in self.digits_]
        if self.code == "residue":
            labels = self.frame_labels_()
            scores = np.zeros((Qn.shape[0], self.n_frames_))
            for j, lp in enumerate(logps):
                scores += lp[:, labels[:, j]]
            index = scores.argmax(axis=1)
            return index.astype(np.int64), scores[np.arange(Qn.shape[0]), index]
        return decode(logps, self.periods_, self.n_frames_, self.decode, int(self.beam_width))

    def frame_log_scores(self, X: Any) -> np.ndarray:
        """Log-probability of every frame for every query, ``(n_q, N)`` (for sequence filtering)."""
        Q = self._check_query(X)
        return plan_for(self).frame_log_scores(Q)

    def localize(self, X: Any, search: Search | None = None) -> Localization:
        """Decode through the serving plan: the exact decode (float32 products, certified in
        float64), or with an inverted file the best of its candidates (``search="flat"``:
        the exact scan all the same)."""
        Q = self._check_query(X)
        return plan_for(self).localize(Q, search)

    # -- storage ------------------------------------------------------------------------
    def footprint(self) -> Footprint:
        self._check_fitted()
        fp = Footprint()
        width = self._digit_width()
        for dc in self.digits_:
            fp.add("encoders", dc.paper_bytes(), dc.nbytes)
            fp.add("masks", width / 8.0, dc.mask_bytes(width))
        if self.normalizer_ is not None:
            self.normalizer_.add_to(fp)
        ivf = getattr(self, "ivf_", None)
        if ivf is not None:
            fp.add("inverted file", 0.0, ivf.nbytes + 8)
        return fp

    def _digit_width(self) -> int:
        """Width of the rows the digits see: the projection's, else the descriptors'."""
        out = None if self.normalizer_ is None else self.normalizer_.n_outputs
        return self.n_features_in_ if out is None else int(out)

    def _to_arrays(self, prefix: str = "") -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        self._check_fitted()
        return encoder_storage.to_arrays(self, self._digit_width(), prefix)

    @classmethod
    def _from_arrays(
        cls,
        params: dict[str, Any],
        arrays: dict[str, np.ndarray],
        meta: dict[str, Any],
        prefix: str = "",
    ) -> PhaseEncoder:
        model = cls(**params)
        encoder_storage.restore(model, arrays, meta, prefix)
        return model

    def _state_arrays(self) -> dict[str, np.ndarray]:
        """The append state (per-class counts and masses), stored beside the tensors."""
        return appending.state_arrays(self)


def _labels(code: str, places: np.ndarray, periods: tuple[int, ...]) -> np.ndarray:
    """Digit labels ``(rows, k)`` of the given places."""
    if code == "residue":
        return np.asarray(places, np.int64)[:, None] % np.asarray(periods, np.int64)[None, :]
    return index_to_labels(places, periods)
