"""The run's report for people: ``report.html`` (:mod:`benchctl.report.html`) with its inline
SVG figures (:mod:`benchctl.report.figures`)."""
