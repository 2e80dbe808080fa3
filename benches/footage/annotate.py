"""Tools for annotating real footage by eye (boxes per person), as
../../docs/evaluation.md#real-footage describes.

usage:
  annotate.py grid VIDEO FRAME OUT.png [--scale S]
      the frame with a grid every 50 px (red every 100, labelled in the frame's own pixels),
      scaled by S (default 2) for viewing
  annotate.py crop VIDEO FRAME X0 Y0 X1 Y1 OUT.png [--scale S]
      a part of the frame, gridded every 10 px (labelled every 50), scaled by S (default 4)
  annotate.py draw ANNOTATIONS.json FRAME OUT.png [--scale S] [--video VIDEO]
      the frame with its annotated boxes drawn back (id above each; dashed when uncertain)

Needs Pillow and the ffmpeg program. Frames are numbered from 0 in decoding order.
"""

import json
import subprocess
import sys
from pathlib import Path

from PIL import Image, ImageDraw


def frame(video, n):
    raw = subprocess.run(
        ["ffmpeg", "-v", "error", "-i", str(video), "-vf", f"select=eq(n\\,{n})",
         "-vsync", "0", "-frames:v", "1", "-f", "image2pipe", "-vcodec", "png", "-"],
        check=True, capture_output=True).stdout
    if not raw:
        sys.exit(f"{video}: no frame {n}")
    from io import BytesIO
    return Image.open(BytesIO(raw)).convert("RGB")


def grid(img, x0, y0, step, label_every, scale):
    w, h = img.size
    big = img.resize((w * scale, h * scale), Image.NEAREST)
    d = ImageDraw.Draw(big)
    first_x = (x0 + step - 1) // step * step
    first_y = (y0 + step - 1) // step * step
    for gx in range(first_x, x0 + w + 1, step):
        major = gx % label_every == 0
        X = (gx - x0) * scale
        d.line([(X, 0), (X, h * scale)], fill=(255, 0, 0) if major else (0, 255, 255), width=1)
        if major:
            d.text((X + 2, 2), str(gx), fill=(255, 255, 0))
    for gy in range(first_y, y0 + h + 1, step):
        major = gy % label_every == 0
        Y = (gy - y0) * scale
        d.line([(0, Y), (w * scale, Y)], fill=(255, 0, 0) if major else (0, 255, 255), width=1)
        if major:
            d.text((2, Y + 2), str(gy), fill=(255, 255, 0))
    return big


def option(args, name, default):
    if name in args:
        i = args.index(name)
        value = args[i + 1]
        del args[i:i + 2]
        return value
    return default


def main(args):
    scale = int(option(args, "--scale", "0"))
    video = option(args, "--video", None)
    cmd = args[0]
    if cmd == "grid":
        img = frame(args[1], int(args[2]))
        grid(img, 0, 0, 50, 100, scale or 2).save(args[3])
    elif cmd == "crop":
        x0, y0, x1, y1 = map(int, args[3:7])
        img = frame(args[1], int(args[2])).crop((x0, y0, x1, y1))
        grid(img, x0, y0, 10, 50, scale or 4).save(args[7])
    elif cmd == "draw":
        ann = json.loads(Path(args[0 + 1]).read_text())
        n = int(args[2])
        video = video or Path(args[1]).parent / ann["clip"]
        img = frame(video, n)
        s = scale or 2
        img = img.resize((img.width * s, img.height * s), Image.BILINEAR)
        d = ImageDraw.Draw(img)
        people = next((f["people"] for f in ann["frames"] if f["frame"] == n), None)
        if people is None:
            sys.exit(f"frame {n} is not annotated")
        for p in people:
            x0, y0, x1, y1 = (v * s for v in p["box"])
            colour = (255, 160, 0) if p.get("uncertain") else (0, 255, 0)
            d.rectangle([x0, y0, x1, y1], outline=colour, width=2)
            d.text((x0 + 2, y0 - 12), str(p["id"]), fill=colour)
        img.save(args[3])
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main(sys.argv[1:])
