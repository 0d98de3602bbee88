"""Readers and writers: CSV (CONTRACTS §0), JSON products, CDF, GOES-R netCDF."""
