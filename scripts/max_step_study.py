"""What ``method.max_step`` (how many ray-march steps one sample may span where the medium is
thin) costs against Mitsuba, with the default's one sample at each pixel centre (run from the
repository root, with the suite's references in build/accuracy/, made by
scripts/accuracy_table.py):

    python scripts/max_step_study.py [SCENE ...] [--resolution 128] [--max-steps 1,2,4,8]

SCENE: names of scenes/accuracy/ (default: every one whose reference exists). One solution per
scene, rendered at the reference's size with each ``--max-steps``; each row gives popvol
compare's relMSE, brightness and bands (dimmest 50 % / middle 40 % / brightest 10 %) against
the reference, and the relMSE and brightness against the first ``--max-steps``' image.
"""
from __future__ import annotations

import dataclasses

import popvol
from popvol import metrics
from spp_study import row, study_args, suite_cases


def main() -> None:
    args, spans = study_args(__doc__, "--max-steps", "1,2,4,8")
    print("| scene, max_step | relMSE | brightness | dim / mid / bright | against the first: relMSE, brightness |")
    print("|---|---|---|---|---|")
    for name, ref, scene, mask in suite_cases(args.scenes, args.resolution, columns=5):
        solution = popvol.solve(scene)
        first = None
        for n in spans:
            img = popvol.render(dataclasses.replace(scene, method=dataclasses.replace(scene.method, max_step=n)),
                                solution)
            first = img if first is None else first
            print(row(f"{name}, {n}", img, ref.image, mask)
                  + f" {metrics.relmse(img, first, mask):.2e}, x{metrics.brightness_ratio(img, first, mask):.4f} |",
                  flush=True)


if __name__ == "__main__":
    main()
