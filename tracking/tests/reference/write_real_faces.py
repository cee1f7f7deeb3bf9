"""Real photographs that scikit-image ships (public domain or free to use, see its
`skimage/data/README.txt`), written as PNG files for the detector measurements of
`cargo run --release -p tracking --example detectors -- --real DIR` (issue 32, item 7).
Test-only: it runs in the venv `scripts/setup.sh` makes at .cache/mediapipe-venv.

    python write_real_faces.py DIR

writes DIR/astronaut.png (NASA's portrait of Eileen Collins), DIR/astronaut-grey.png
(three equal channels), DIR/camera.png (the grey "cameraman", a face about a tenth of
the frame) and the LFW subset (Labeled Faces in the Wild: 100 face crops and 100
background crops, 25 x 25 grey) as DIR/lfw-face-NNN.png and DIR/lfw-background-NNN.png."""

import sys
from pathlib import Path

import numpy as np
from PIL import Image
from skimage import data


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    rgb = data.astronaut()
    Image.fromarray(rgb).save(out / "astronaut.png")
    grey = np.asarray(Image.fromarray(rgb).convert("L"))
    Image.fromarray(np.stack([grey] * 3, axis=-1)).save(out / "astronaut-grey.png")
    Image.fromarray(data.camera()).convert("RGB").save(out / "camera.png")
    lfw = data.lfw_subset()
    for i, crop in enumerate(lfw):
        name = f"lfw-face-{i:03}.png" if i < 100 else f"lfw-background-{i - 100:03}.png"
        pixels = crop if crop.dtype == np.uint8 else np.round(crop * 255).astype(np.uint8)
        Image.fromarray(pixels).convert("RGB").save(out / name)
    print(f"wrote {len(lfw) + 3} images to {out}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: write_real_faces.py DIR")
    main(Path(sys.argv[1]))
