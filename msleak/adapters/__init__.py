"""Files read into the models' types: a beam model loaded for an MS (``beams``, and
EveryBeam called directly, ``everybeam``), FITS sky cubes (``sky_fits``) and makesourcedb
skies (``skymodel``). They read through :mod:`msleak.io` where they can
(docs/architecture.md)."""
