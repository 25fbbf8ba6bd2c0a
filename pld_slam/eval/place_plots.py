"""PNG plots of place recognition (`pld_slam.loop.places`): the similarity heat map and the
precision-recall curve, drawn off-screen as `pld_slam.eval.plots` draws trajectories.

The heat map shows at most `HEATMAP_MAX_PIXELS` rows and columns: a longer set is shown
every ``k``-th image (the axes still count images), since a figure cannot show more
pixels than it has and the full matrix is in ``similarity.npy``.
"""

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from pld_slam.eval.plots import FIGURE_SIZE_IN, save_figure
from pld_slam.loop.places import PlaceScores

HEATMAP_MAX_PIXELS = 1000
"""Largest number of rows (and columns) of the similarity heat map before it is subsampled."""


def plot_similarity_matrix(path_png, similarity: np.ndarray, title: str = "Place similarity") -> None:
    """Write the similarity matrix (N, N) (higher = more similar, NaN = not scored) as a heat map PNG.

    Rows are query images, columns database images; unscored pairs are left white.
    """
    similarity = np.asarray(similarity, dtype=np.float64)
    n = len(similarity)
    step = max(1, -(-n // HEATMAP_MAX_PIXELS))
    shown = np.ma.masked_invalid(similarity[::step, ::step])
    colormap = colormaps["viridis"].with_extremes(bad="white")
    figure = Figure(figsize=FIGURE_SIZE_IN)
    axes = figure.add_subplot()
    extent = (-0.5, n - 0.5, n - 0.5, -0.5)
    image = axes.imshow(shown, cmap=colormap, interpolation="nearest", extent=extent, aspect="equal")
    figure.colorbar(image, ax=axes, label="similarity (higher = more similar)")
    axes.set_xlabel("database image")
    axes.set_ylabel("query image")
    axes.set_title(title if step == 1 else f"{title} (one image in {step} shown)")
    save_figure(figure, path_png)


def plot_precision_recall(path_png, scores: PlaceScores, title: str = "Place recognition") -> None:
    """Write the precision-recall curve of the best matches as a PNG, with AP and recall at 100 % precision."""
    figure = Figure(figsize=FIGURE_SIZE_IN)
    axes = figure.add_subplot()
    # Between recall R_{k-1} and R_k the precision is P_k ("pre" steps): the area is the AP.
    recall = np.r_[0.0, scores.recall]
    precision = np.r_[scores.precision[:1], scores.precision]
    label = (f"AP {scores.average_precision:.3f}, recall@100%P {scores.recall_at_full_precision:.3f}, "
             f"top-1 {scores.top1_accuracy:.3f}")
    axes.step(recall, precision, "b-", where="pre", label=label)
    axes.set_xlim(0.0, 1.02)
    axes.set_ylim(0.0, 1.02)
    axes.set_xlabel("recall")
    axes.set_ylabel("precision")
    axes.set_title(f"{title}: {scores.n_with_true_match} of {scores.n_queries} queries with a true match")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="lower left")
    save_figure(figure, path_png)
