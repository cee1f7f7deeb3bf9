"""MediaPipe's own Face Mesh (the legacy `face_mesh` solution of the PyPI wheel
mediapipe==0.10.14, static-image mode: BlazeFace, then Face Mesh on the detection's crop)
on each image given, for tests/mediapipe.rs's reference parity. Test-only: it runs in the
venv `scripts/setup.sh` makes at .cache/mediapipe-venv from
tests/reference/requirements.txt.

    python mediapipe_face_mesh.py [--write-astronaut DIR] IMAGE...

prints one JSON object: for each IMAGE its 468 points [x, y, z] in pixels (z at x's scale),
or null when no face is found. `--write-astronaut DIR` first writes scikit-image's
public-domain `astronaut` photograph (NASA) as DIR/astronaut.png and a grayscale copy
(three equal channels) as DIR/astronaut-grey.png."""

import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image


def main(argv: list[str]) -> None:
    if argv[:1] == ["--write-astronaut"]:
        from skimage import data

        out = Path(argv[1])
        rgb = data.astronaut()
        Image.fromarray(rgb).save(out / "astronaut.png")
        grey = np.asarray(Image.fromarray(rgb).convert("L"))
        Image.fromarray(np.stack([grey] * 3, axis=-1)).save(out / "astronaut-grey.png")
        argv = argv[2:]
    import mediapipe as mp

    result = {}
    with mp.solutions.face_mesh.FaceMesh(static_image_mode=True, max_num_faces=1, refine_landmarks=False, min_detection_confidence=0.5) as mesh:
        for path in argv:
            image = np.asarray(Image.open(path).convert("RGB"))
            h, w = image.shape[:2]
            found = mesh.process(image).multi_face_landmarks
            result[path] = None if not found else [[p.x * w, p.y * h, p.z * w] for p in found[0].landmark]
    json.dump(result, sys.stdout)


if __name__ == "__main__":
    main(sys.argv[1:])
