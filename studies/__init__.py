"""Research studies of nbv_prob_cnn: one-off analyses, comparisons and soak harnesses, with their
results under ``studies/results/``. They use the product (:mod:`nbv_prob_cnn`); the product never
imports them. Run one with ``nbv study NAME [args]`` (or ``python -m studies NAME [args]``);
``studies/README.md`` lists each study's question, command and result page."""
