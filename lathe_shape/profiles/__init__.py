"""Profiles of solids of revolution: polylines, cubic B-splines and arc specs
(numpy only, no Mitsuba)."""
