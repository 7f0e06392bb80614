"""Text-captcha synthesiser (seed 04): labelled 4-digit captchas in the style of a real set, and the
seed's line-removal / binarisation preprocessing.

The style imitates (without copying any pixel of) GT-ZhangAcer's CaptchaDataset
(https://github.com/GT-ZhangAcer/CaptchaDataset, MIT, (c) 2020 GT-Zhang; credit asked by its
author), kept at ``../shared/data/captcha/gtzhang_digits4``: 70x30 JPEGs, a pale pastel background,
four dark serif digits of one colour each at roughly even spacing, and a few short thin dark
noise lines. Digits are drawn with the machine's TrueType fonts (serif first; OpenCV's Hershey
fonts if none is found), rotated, scaled, sheared and jittered, the image is gently warped and
JPEG-compressed like the real ones.

>>> images, labels = synthesize_captchas(64, seed=0)        # (64, 30, 70, 3) uint8 RGB, (64, 4) int
>>> binary = remove_lines(images[0])                          # (30, 70) uint8, 255 = ink
>>> real = load_real_captchas()                               # the real set, split by file
"""
from __future__ import annotations

import csv
import functools
import glob
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, ImageDraw, ImageFont

#: the real set's fixed split by file index (images/<i>.jpg): train, validation, test
SPLIT = {"train": range(0, 600), "validation": range(600, 700), "test": range(700, 1000)}
FONT_GLOBS = ("/usr/share/fonts/**/*Serif*.ttf", "/usr/share/fonts/**/*Times*.ttf",
              "/usr/share/fonts/**/*Liberation*Serif*.ttf")


@dataclass(frozen=True)
class CaptchaStyle:
    """How captchas look: size, glyph geometry, colours and noise (defaults: the real set's look)."""

    height_px: int = 30
    width_px: int = 70
    n_chars: int = 4
    glyph_height_px: tuple[float, float] = (15.0, 18.5)   # digit height range
    glyph_aspect: tuple[float, float] = (0.75, 0.95)       # horizontal squeeze (the real font is narrow)
    rotation_deg: float = 8.0                              # +- per digit
    shear: float = 0.15                                    # +- per digit
    jitter_px: tuple[float, float] = (1.5, 2.0)            # +- (x, y) per digit
    n_lines: tuple[int, int] = (4, 10)                     # noise lines per image (inclusive)
    line_length_px: tuple[float, float] = (6.0, 20.0)
    border_prob: float = 1.0                               # a dark 1-px frame
    warp_px: float = 0.8                                   # sine warp amplitude
    jpeg_quality: tuple[int, int] = (60, 90)
    supersample: int = 3
    background: tuple[float, float] = (195.0, 248.0)     # per-channel range of the pastel background
    ink: tuple[float, float] = (15.0, 140.0)             # per-channel range of each digit's colour


#: a deliberately crude style (Hershey strokes, black on white, no noise): a wide sim-to-real gap
PLAIN = CaptchaStyle(rotation_deg=0.0, shear=0.0, jitter_px=(0.5, 0.5), n_lines=(0, 0), border_prob=0.0,
                     warp_px=0.0, jpeg_quality=(100, 100), background=(255.0, 255.0), ink=(0.0, 0.0))


def find_fonts() -> tuple[str, ...]:
    """Serif TrueType fonts found on the machine (``fc-list``'s directories), sorted; may be empty."""
    found: set[str] = set()
    for pattern in FONT_GLOBS:
        found |= set(glob.glob(pattern, recursive=True))
    # light/extra-light weights and math fonts do not look like the real set's glyphs
    # upright regular/bold weights only: the real set's digits are upright serif
    return tuple(sorted(f for f in found if not any(k in f for k in ("Light", "Math", "Italic", "Oblique"))))


@functools.lru_cache(maxsize=64)
def _font(path: str, size: int) -> ImageFont.FreeTypeFont:
    return ImageFont.truetype(path, size)


def _glyph(char: str, height_px: float, rng: np.random.Generator, fonts: tuple[str, ...], ss: int) -> np.ndarray:
    """A tight alpha mask (float, 0..1) of one character at ``ss`` x supersampling."""
    target = height_px * ss
    if fonts:
        font = _font(fonts[rng.integers(len(fonts))], int(round(target * 1.38)))  # digit cap ~0.73 em
        left, top, right, bottom = font.getbbox(char)
        canvas = Image.new("L", (right - left + 4, bottom - top + 4), 0)
        ImageDraw.Draw(canvas).text((2 - left, 2 - top), char, fill=255, font=font)
        mask = np.asarray(canvas, np.float32) / 255.0
    else:
        face = (cv2.FONT_HERSHEY_COMPLEX, cv2.FONT_HERSHEY_TRIPLEX)[rng.integers(2)]
        scale = target / 22.0
        (w, h), _ = cv2.getTextSize(char, face, scale, max(1, ss))
        mask = np.zeros((h + 4 * ss, w + 4 * ss), np.uint8)
        cv2.putText(mask, char, (2 * ss, h + 2 * ss), face, scale, 255, max(1, int(1.4 * ss)), cv2.LINE_AA)
        mask = mask.astype(np.float32) / 255.0
    ys, xs = np.nonzero(mask > 0.05)
    return mask[ys.min():ys.max() + 1, xs.min():xs.max() + 1] if len(ys) else mask


def _transform(mask: np.ndarray, height_px: float, aspect: float, rot_deg: float, shear: float, ss: int) -> np.ndarray:
    """Scale the glyph to ``height_px`` (x ss), shear and rotate it about its centre, padded."""
    h, w = mask.shape
    s = height_px * ss / h
    pad = int(0.5 * max(h, w) * s) + 2
    a = np.array([[s * aspect, shear * s, 0.0], [0.0, s, 0.0]])
    size = (int(w * s * aspect) + 2 * pad, int(h * s) + 2 * pad)
    a[:, 2] = [pad - shear * s * h / 2, pad]
    rot = cv2.getRotationMatrix2D((size[0] / 2, size[1] / 2), rot_deg, 1.0)
    m = rot @ np.vstack([a, [0, 0, 1]])
    return cv2.warpAffine(mask, m, size, flags=cv2.INTER_LINEAR)


def _colour(rng: np.random.Generator, lo: int, hi: int) -> np.ndarray:
    return rng.uniform(lo, hi, 3)


def render_captcha(text: str, rng: np.random.Generator, style: CaptchaStyle = CaptchaStyle(), *,
                   fonts: tuple[str, ...] | None = None) -> np.ndarray:
    """One captcha showing ``text``.

    Parameters
    ----------
    text : str
        The characters, drawn left to right at roughly even spacing.
    rng : numpy.random.Generator
        All randomness (glyph geometry, colours, lines, compression).
    style : CaptchaStyle
    fonts : tuple of str, optional
        TrueType files to draw with; default ``find_fonts()`` (Hershey fonts if empty).

    Returns
    -------
    numpy.ndarray
        (height_px, width_px, 3) uint8 RGB.
    """
    fonts = find_fonts() if fonts is None else fonts
    ss, H, W = style.supersample, style.height_px, style.width_px
    bg = _colour(rng, *style.background)
    img = np.ones((H * ss, W * ss, 3), np.float32) * bg
    slot = W * 0.86 / len(text)
    for i, ch in enumerate(text):
        gh = rng.uniform(*style.glyph_height_px)
        glyph = _transform(_glyph(ch, gh, rng, fonts, ss), gh, rng.uniform(*style.glyph_aspect),
                           rng.uniform(-1, 1) * style.rotation_deg, rng.uniform(-1, 1) * style.shear, ss)
        cx = (i + 0.66) * slot + rng.uniform(-1, 1) * style.jitter_px[0]
        cy = H / 2 + rng.uniform(-1, 1) * style.jitter_px[1]
        gy, gx = glyph.shape
        x0, y0 = int(round(cx * ss - gx / 2)), int(round(cy * ss - gy / 2))
        ys, xs = slice(max(y0, 0), min(y0 + gy, H * ss)), slice(max(x0, 0), min(x0 + gx, W * ss))
        alpha = glyph[ys.start - y0:ys.stop - y0, xs.start - x0:xs.stop - x0, None]
        ink = _colour(rng, *style.ink)
        img[ys, xs] = img[ys, xs] * (1 - alpha) + ink * alpha
    for _ in range(rng.integers(style.n_lines[0], style.n_lines[1] + 1)):
        p = rng.uniform([0, 0], [W, H])
        ang, length = rng.uniform(0, np.pi), rng.uniform(*style.line_length_px)
        q = p + length * np.array([np.cos(ang), np.sin(ang)])
        grey = rng.uniform(80, 150)
        col = tuple(float(c) for c in np.clip(grey + rng.uniform(-25, 25, 3), 0, 255))
        cv2.line(img, tuple(int(v) for v in p * ss), tuple(int(v) for v in q * ss), col, max(1, (2 * ss) // 3), cv2.LINE_AA)
    img = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)
    img = _warp(img, rng, style.warp_px)
    if rng.random() < style.border_prob:   # the real set has a near-black 1-px frame on every side (drawn after the warp)
        dark = rng.uniform(0, 25)
        img[[0, -1], :] = dark
        img[:, [0, -1]] = dark
    quality = int(rng.integers(style.jpeg_quality[0], style.jpeg_quality[1] + 1))
    ok, buf = cv2.imencode(".jpg", np.clip(img, 0, 255).astype(np.uint8)[..., ::-1],
                           [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()


def _warp(img: np.ndarray, rng: np.random.Generator, amp_px: float) -> np.ndarray:
    """A gentle sine displacement (the real set's strokes are not perfectly straight)."""
    if amp_px <= 0:
        return img
    H, W = img.shape[:2]
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    k, ph = rng.uniform(0.08, 0.2, 2), rng.uniform(0, 2 * np.pi, 2)
    mx = xx + amp_px * np.sin(k[0] * yy + ph[0])
    my = yy + amp_px * np.sin(k[1] * xx + ph[1])
    return cv2.remap(img, mx.astype(np.float32), my.astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def synthesize_captchas(n: int, *, seed: int = 0, style: CaptchaStyle = CaptchaStyle(),
                        fonts: tuple[str, ...] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random digit captchas and their labels.

    Returns
    -------
    images : numpy.ndarray
        (n, height_px, width_px, 3) uint8 RGB.
    labels : numpy.ndarray
        (n, n_chars) int64 digits 0..9.
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    rng = np.random.default_rng(seed)
    fonts = find_fonts() if fonts is None else fonts
    labels = rng.integers(0, 10, (n, style.n_chars))
    images = np.empty((n, style.height_px, style.width_px, 3), np.uint8)
    for i in range(n):
        images[i] = render_captcha("".join(map(str, labels[i])), rng, style, fonts=fonts)
    return images, labels


def remove_lines(image: np.ndarray, *, block_px: int = 15, offset: float = 12.0, min_thickness_px: int = 2) -> np.ndarray:
    """The seed's preprocessing: binarise, then drop thin noise lines by iterated neighbour masks.

    A pixel stays ink only while its right and lower neighbours are ink too (the seed's
    ``&=`` of shifted masks, i.e. a binary erosion by a ``min_thickness_px`` square); the
    surviving stroke cores are then grown back inside the original ink (a reconstruction), so
    digit strokes keep their shape and 1-px lines vanish.

    Parameters
    ----------
    image : numpy.ndarray
        (H, W, 3) uint8 RGB or (H, W) grey.
    block_px : int
        Adaptive-threshold window (odd, >= 3).
    offset : float
        Grey levels below the local mean that count as ink.
    min_thickness_px : int
        Strokes thinner than this are removed.

    Returns
    -------
    numpy.ndarray
        (H, W) uint8, 255 = ink, 0 = background.
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.size == 0:
        raise ValueError(f"expected an (H, W) or (H, W, 3) image, got shape {img.shape}")
    if block_px < 3 or block_px % 2 == 0:
        raise ValueError(f"block_px must be odd and >= 3, got {block_px}")
    grey = cv2.cvtColor(img.astype(np.uint8), cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img.astype(np.uint8)
    ink = cv2.adaptiveThreshold(grey, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, block_px, offset) > 0
    core = ink.copy()
    for shift in range(1, min_thickness_px):
        core[:, :-shift] &= ink[:, shift:]
        core[:-shift, :] &= ink[shift:, :]
        core[:, -shift:] = False
        core[-shift:, :] = False
    grown = core
    kernel = np.ones((3, 3), np.uint8)
    for _ in range(min_thickness_px):
        grown = cv2.dilate(grown.astype(np.uint8), kernel).astype(bool) & ink
    return grown.astype(np.uint8) * 255


def shared_captcha_dir() -> Path:
    """``$TETHER_SHARED_DATA/captcha/gtzhang_digits4`` or ``<repo>/../shared/data/...`` (at call time)."""
    base = os.environ.get("TETHER_SHARED_DATA")
    root = Path(base) if base else Path(__file__).resolve().parents[2] / "shared" / "data"
    return root / "captcha" / "gtzhang_digits4"


def load_real_captchas(root: str | Path | None = None, *, split: str | None = None) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The real captchas (GT-ZhangAcer/CaptchaDataset, MIT), read in place, never copied.

    Parameters
    ----------
    root : path, optional
        The ``gtzhang_digits4`` folder (``labels.csv``, ``images/``); default ``shared_captcha_dir()``.
    split : {"train", "validation", "test"}, optional
        The fixed split by file (``SPLIT``: files 0-599, 600-699, 700-999); default all.

    Returns
    -------
    images : (N, 30, 70, 3) uint8 RGB
    labels : (N, 4) int64
    files : list of str
    """
    root = Path(root) if root is not None else shared_captcha_dir()
    table = root / "labels.csv"
    if not table.exists():
        raise FileNotFoundError(f"real captchas not found at {root} (set TETHER_SHARED_DATA or pass root=)")
    if split is not None and split not in SPLIT:
        raise ValueError(f"split must be one of {sorted(SPLIT)}, got {split!r}")
    with open(table, newline="") as f:
        rows = list(csv.DictReader(f))
    keep = set(SPLIT[split]) if split else None
    images, labels, files = [], [], []
    for row in rows:
        index = int(Path(row["file"]).stem)
        if keep is not None and index not in keep:
            continue
        bgr = cv2.imread(str(root / row["file"]), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"{root / row['file']}: not a readable image")
        images.append(bgr[..., ::-1])
        labels.append([int(c) for c in row["text"]])
        files.append(row["file"])
    return np.stack(images), np.asarray(labels, np.int64), files
