"""The jobs: the one residual job (:mod:`~boresight.jobs.residual`) and what runs through it, the
paper's reproduction (:mod:`~boresight.jobs.paper`), the suppression tables
(:mod:`~boresight.jobs.suppression`) and sweeps (:mod:`~boresight.jobs.sweep`), with their
resources (:mod:`~boresight.jobs.resources`) and background transforms
(:mod:`~boresight.jobs.transforms`)."""
