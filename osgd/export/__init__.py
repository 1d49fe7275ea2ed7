"""Exports of a data dir for readers that are not osgd (:mod:`osgd.export.hf`: a Hugging Face dataset folder).

The text and JSON formats (osgd, cornell, coco) are in :mod:`osgd.samples.export`, which dispatches here.
"""
