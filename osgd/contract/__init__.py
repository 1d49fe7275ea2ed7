"""The data contract between the generator (osgd) and its readers (togcrf, users' code).

Everything a reader of the dataset needs, and nothing else: it imports only
numpy, pyarrow and OpenCV (``tests/test_contract.py`` enforces it).

- :mod:`osgd.contract.taxonomy`: the categories, the task labels of Table I
  and the object parts (the vocabulary);
- :mod:`osgd.contract.schemas`: every Parquet table;
- :mod:`osgd.contract.encoding`: the PNG encodings of depth and masks;
- :mod:`osgd.contract.files`: a data dir's files, in a folder or an object store;
- :mod:`osgd.contract.shards`: find, verify and read finished shards;
- :mod:`osgd.contract.samples`: the training samples as numpy arrays.
- :mod:`osgd.contract.process_exit`: how a command that has read or written
  shards ends its process (pyarrow's threads outlive the interpreter).

The generator writes through the same definitions, so a shard and its
reader cannot disagree.
"""
