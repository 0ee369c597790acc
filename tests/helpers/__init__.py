"""Helpers shared by the tests: small scene folders (:mod:`.scenes`), reading recordings back
(:mod:`.rrd`) and the import graph of the packages (:mod:`.imports`)."""
