"""The paper's own figures, to print beside lenspair's (labelled as published).

From Fumagalli et al., "Fast Image-Anomaly Mitigation for Autonomous Mobile
Robots" (https://arxiv.org/abs/2109.01889): measured by the authors on the
Raindrop test set or their rig data, on a GPU, after full training (Adam lr
2e-4, batch 8, 200 epochs, early stopping patience 10, 5613 pairs of
540x360 mono). They are not reproduced by lenspair: they are printed so
that lenspair's short CPU runs are read against them.
"""

from dataclasses import dataclass

PAPER = "Fumagalli et al. (published)"


@dataclass(frozen=True)
class PublishedRow:
    """One published figure set.

    Attributes:
        table: which of the paper's tables.
        name: row label.
        ssim: SSIM.
        psnr_db: PSNR, dB.
        gpu_s: seconds per image on the GPU (RTX 2080), when published.
        cpu_s: seconds per image on the CPU (Intel Core i7 10th gen), when published.

    """

    table: str
    name: str
    ssim: float
    psnr_db: float
    gpu_s: float | None = None
    cpu_s: float | None = None


ABLATION = "ablation, Raindrop test set"
INITIALISATION = "initialisation, authors' rig data"
STATE_OF_THE_ART = "state of the art, Raindrop test set"

PUBLISHED: tuple[PublishedRow, ...] = (
    PublishedRow(ABLATION, "input", 0.851, 24.09),
    PublishedRow(ABLATION, "G", 0.869, 27.12),
    PublishedRow(ABLATION, "G+E", 0.898, 29.15),
    PublishedRow(ABLATION, "G+E+A", 0.909, 29.84),
    PublishedRow(INITIALISATION, "raw input", 0.760, 19.34),
    PublishedRow(INITIALISATION, "random init", 0.787, 22.36),
    PublishedRow(INITIALISATION, "Porav's synthetic", 0.791, 22.15),
    PublishedRow(INITIALISATION, "the paper's synthetic", 0.813, 24.77),
    PublishedRow(STATE_OF_THE_ART, "DeRaindrop", 0.921, 31.50, 0.262, 4.317),
    PublishedRow(STATE_OF_THE_ART, "Porav et al.", 0.902, 31.55, 0.091, 2.780),
    PublishedRow(STATE_OF_THE_ART, "the paper (GEA)", 0.909, 29.84, 0.006, 0.542),
)


def published_markdown(tables: tuple[str, ...] | None = None) -> str:
    """The published rows as a Markdown table, each labelled with its table."""
    lines = [
        f"Published figures ({PAPER}: Raindrop test set or the authors' rig data, GPU, "
        "full training; not measured here):",
        "",
        "| published table | row | SSIM | PSNR (dB) | GPU s | CPU s |",
        "|---|---|---|---|---|---|",
    ]
    for row in PUBLISHED:
        if tables is not None and row.table not in tables:
            continue
        gpu = "" if row.gpu_s is None else f"{row.gpu_s:.3f}"
        cpu = "" if row.cpu_s is None else f"{row.cpu_s:.3f}"
        lines.append(
            f"| {row.table} | {row.name} | {row.ssim:.3f} | {row.psnr_db:.2f} | {gpu} | {cpu} |"
        )
    return "\n".join(lines)
