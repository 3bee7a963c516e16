"""Layer 3: design methods over one problem, each returning one Result.

The formulations (nlp, multishape, tip, clearance, robust, obstacles, correction) are terms, rows and guesses on one
multiple-shooting transcription (``methods.transcription``); the greedy baseline is its own algorithm on the same model,
pairing, error and bounds (``methods.common``). Which runs a problem asks for is the pipeline's (``vine_nlp.pipeline``)."""
