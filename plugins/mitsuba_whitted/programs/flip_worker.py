"""Reads pickled pairs of images (reference, test) on stdin and writes the
mean HDR-FLIP and its map of each to stdout, until stdin closes (see
:func:`mitsuba_whitted.compare.metrics.flip_error`)."""

import pickle
import sys

import flip_evaluator
import numpy as np


def main(read=sys.stdin.buffer, write=sys.stdout.buffer) -> None:
    while read.peek(1):
        reference, image = pickle.load(read)
        error_map, mean, _ = flip_evaluator.evaluate(reference, image, "HDR", applyMagma=False)
        pickle.dump((float(mean), np.asarray(error_map)[..., 0]), write, protocol=5)
        write.flush()


if __name__ == "__main__":
    main()
