"""A contact sheet of a video: frames at evenly spaced times, stacked into one JPEG.

A video in results/ is watched once; its failure mode is cited many times. The sheet lets a
report show what happened (a grasp closing over a flat object, a box slipping out) beside the
numbers, and lets a reader check it without a player.

    python scripts/video_frames.py results/cpu-ycb-2026-11-29/media/X.mp4 --frames 6
    # -> results/cpu-ycb-2026-11-29/media/X-frames.jpg (6 frames top to bottom, times in the corner)
"""

from __future__ import annotations

from pathlib import Path

import click
import imageio_ffmpeg
import numpy as np
from PIL import Image, ImageDraw


def read_frames(video: Path, count: int) -> tuple[list[tuple[int, np.ndarray]], float, int]:
    """``count`` frames of ``video`` at evenly spaced indices (first and last included) as
    (index, (H, W, 3) uint8 array) pairs, the frame rate and the number of frames. The video is
    counted first and then streamed, keeping only the picked frames (a 6 s, 1920x360 video's
    every frame would be ~370 MB)."""
    total = imageio_ffmpeg.count_frames_and_secs(str(video))[0]
    if total < 1:
        raise click.ClickException(f"{video} has no frames: film it again (trainer play)")
    picks = set(np.linspace(0, total - 1, min(count, total)).round().astype(int).tolist())
    reader = imageio_ffmpeg.read_frames(str(video))
    meta = next(reader)
    width, height = meta["size"]
    picked = [(index, np.frombuffer(raw, np.uint8).reshape(height, width, 3))
              for index, raw in enumerate(reader) if index in picks]
    reader.close()
    return picked, float(meta["fps"]), total


def contact_sheet(picked: list[tuple[int, np.ndarray]], fps: float, width: int) -> Image.Image:
    """The picked frames, each scaled to ``width`` pixels, top to bottom (a ``trainer play``
    video is its episodes side by side, so a row is one moment of every episode), each labelled
    with its time in seconds."""
    tiles = []
    for index, frame in picked:
        tile = Image.fromarray(frame)
        tile = tile.resize((width, round(tile.height * width / tile.width)))
        ImageDraw.Draw(tile).text((6, 4), f"{index / fps:.1f} s", fill=(255, 255, 255))
        tiles.append(tile)
    sheet = Image.new("RGB", (width, tiles[0].height * len(tiles)))
    for i, tile in enumerate(tiles):
        sheet.paste(tile, (0, i * tile.height))
    return sheet


@click.command()
@click.argument("video", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--frames", "count", default=6, show_default=True, help="Frames on the sheet.")
@click.option("--width", default=960, show_default=True, help="Pixels across the sheet.")
@click.option("--out", type=click.Path(path_type=Path), help="[VIDEO's name]-frames.jpg")
def main(video: Path, count: int, width: int, out: Path | None) -> None:
    """Stack COUNT evenly spaced frames of VIDEO into one JPEG."""
    if count < 1 or width < 16:
        raise click.ClickException("--frames must be >= 1 and --width >= 16")
    picked, fps, total = read_frames(video, count)
    sheet = contact_sheet(picked, fps, width)
    out = out or video.with_name(f"{video.stem}-frames.jpg")
    sheet.save(out, quality=85)
    click.echo(f"{out}: {sheet.width}x{sheet.height}, {len(picked)} of {total} frames at "
               f"{fps:g} fps")


if __name__ == "__main__":
    main()
