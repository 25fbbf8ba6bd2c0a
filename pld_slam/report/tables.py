"""The paper's table layout from the rows of an ablation: Markdown, LaTeX and CSV.

Rows are sequences, each variant a column pair (t, R), the best value of each metric
per row in bold, and a mean row at the bottom.

What t and R are. The paper's Table I reports an "absolute RMSE" of translation and of
rotation without defining them further. We take t = the RMSE of the position error
(ATE, metres) after the SE(3) Umeyama alignment of the positions, and R = the RMSE of the
rotation angle of ``R_gt^T R_est`` (degrees) after the best world rotation of the
orientations (`pld_slam.eval.metrics.fit_orientation_alignment`; the position alignment
leaves the roll about a straight drive to noise), both per matched pose and computed by
evo's APE (`pld_slam.eval.metrics.evaluate`): "absolute" as in evo and the TUM
benchmark, no scale since stereo has it. The table header says so.

The mean row averages each column over the sequences that every variant finished (a
cell that failed or has no ground truth would otherwise make the means of two variants
cover different sequences); the header says how many. A cell without a value shows
"fail" (failed), "stop" (ended early by itself: its figure covers fewer frames, so it is
left out) or "n/a" (no ground truth).
"""

from dataclasses import dataclass

import numpy as np
import pandas as pd

METRICS = (("t", "ate_rmse_m", 4), ("R", "ate_rot_rmse_deg", 3))
"""Each column of a variant's pair: its label, the row key it shows, the decimals shown."""

_DECIMALS = {label: decimals for label, _, decimals in METRICS}

HEADER = ("t: translation ATE RMSE [m] after SE(3) alignment, R: absolute rotation RMSE [deg] after "
          "rotation alignment (evo APE, per pose). Bold: best per row.")


@dataclass(frozen=True)
class PaperTable:
    """An ablation's results in the paper's layout.

    Attributes
    ----------
    values : pandas.DataFrame
        Index: sequences, then ``mean``; columns: (variant, metric label) pairs; NaN
        where a cell has no value.
    marks : pandas.DataFrame
        Same shape: why a value is missing (``fail``, ``stop``, ``n/a``), else empty.
    mean_over : int
        Sequences the mean row averages over.
    """

    values: pd.DataFrame
    marks: pd.DataFrame
    mean_over: int

    def best(self) -> pd.DataFrame:
        """Booleans of the same shape: the smallest value of each metric in its row, as
        shown (values equal to the decimals shown are all best)."""
        best = pd.DataFrame(False, index=self.values.index, columns=self.values.columns)
        for label, _, decimals in METRICS:
            block = self.values.xs(label, axis=1, level=1).round(decimals)
            lowest = block.min(axis=1)
            for variant in block.columns:
                best[(variant, label)] = block[variant].notna() & (block[variant] == lowest)
        return best

    def text(self, sequence: str, column: tuple[str, str]) -> str:
        """A cell as plain text: the formatted value, or why it has none."""
        value = self.values.at[sequence, column]
        if np.isnan(value):
            return self.marks.at[sequence, column] or "n/a"
        return f"{value:.{_DECIMALS[column[1]]}f}"


def paper_table(rows: list[dict], sequences: list[str], variants: list[str]) -> PaperTable:
    """The `PaperTable` of the cell rows ``rows`` (``store.ROW_COLUMNS``) in the given order."""
    columns = pd.MultiIndex.from_tuples([(v, label) for v in variants for label, _, _ in METRICS])
    values = pd.DataFrame(np.nan, index=sequences, columns=columns)
    marks = pd.DataFrame("", index=sequences, columns=columns)
    for row in rows:
        if row["sequence"] not in values.index or row["variant"] not in variants:
            continue
        for label, key, _ in METRICS:
            column = (row["variant"], label)
            if row["status"] == "ok" and row[key] is not None:
                values.at[row["sequence"], column] = row[key]
            else:
                marks.at[row["sequence"], column] = {"failed": "fail", "stopped": "stop"}.get(row["status"], "n/a")
    complete = values.notna().all(axis=1)
    values.loc["mean"] = values[complete].mean() if complete.any() else np.nan
    marks.loc["mean"] = ""
    return PaperTable(values=values, marks=marks, mean_over=int(complete.sum()))


def _mean_label(table: PaperTable) -> str:
    return f"mean ({table.mean_over})"


def to_markdown(table: PaperTable) -> str:
    """The table as GitHub Markdown: a header line, then one row per sequence and the mean."""
    best = table.best()
    head = ["sequence"] + [f"{variant} {label}" for variant, label in table.values.columns]
    lines = [f"{HEADER} Mean over the {table.mean_over} sequences every variant finished.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for sequence in table.values.index:
        cells = [f"**{table.text(sequence, c)}**" if best.at[sequence, c] else table.text(sequence, c)
                 for c in table.values.columns]
        name = _mean_label(table) if sequence == "mean" else sequence
        lines.append("| " + " | ".join([name, *cells]) + " |")
    return "\n".join(lines) + "\n"


def _latex_escape(text: str) -> str:
    """``text`` safe in LaTeX body text."""
    for char, escaped in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("$", r"\$"),
                          ("#", r"\#"), ("_", r"\_"), ("{", r"\{"), ("}", r"\}")):
        text = text.replace(char, escaped)
    return text


def to_latex(table: PaperTable) -> str:
    """The table as a booktabs ``tabular`` (needs ``\\usepackage{booktabs}``), variants as
    two-column groups, bold best per row, the mean row under a rule."""
    best = table.best()
    variants = list(dict.fromkeys(v for v, _ in table.values.columns))
    n = len(table.values.columns)
    lines = [f"% {HEADER} Mean over the {table.mean_over} sequences every variant finished.",
             r"\begin{tabular}{l" + "r" * n + "}", r"\toprule",
             " & ".join(["Sequence"] + [rf"\multicolumn{{2}}{{c}}{{{_latex_escape(v)}}}" for v in variants]) + r" \\",
             " ".join(rf"\cmidrule(lr){{{2 + 2 * i}-{3 + 2 * i}}}" for i in range(len(variants))),
             " & ".join([""] + [label for _, label in table.values.columns]) + r" \\", r"\midrule"]
    for sequence in table.values.index:
        if sequence == "mean":
            lines.append(r"\midrule")
        cells = [(rf"\textbf{{{table.text(sequence, c)}}}" if best.at[sequence, c] else table.text(sequence, c))
                 for c in table.values.columns]
        name = _mean_label(table) if sequence == "mean" else sequence
        lines.append(" & ".join([_latex_escape(name), *cells]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines) + "\n"


def to_csv(table: PaperTable) -> str:
    """The values as CSV: one row per sequence and the mean, columns ``VARIANT t`` and ``VARIANT R``."""
    flat = table.values.copy()
    flat.columns = [f"{variant} {label}" for variant, label in flat.columns]
    flat.index.name = "sequence"
    return flat.to_csv(float_format="%.6g")
