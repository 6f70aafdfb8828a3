"""Files: Measurement Sets, FITS files and image cubes, UVBeam files, casacore measures and
msleak's own products, read into arrays and plain records (no stage package is imported).

Every casacore call of msleak goes through this package (or a module that imports it), so
casacore is pointed at a current leap-second table here, before it first reads its data
(:func:`msleak.io.casacore_data.configure_casacore_measures`; nothing when the user
configured casacore themselves).
"""

from msleak.io.casacore_data import configure_casacore_measures

configure_casacore_measures()
