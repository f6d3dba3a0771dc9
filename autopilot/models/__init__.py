"""The fuzzy models the controller flies: their evaluation (ts_model), file format
(model_file), regressors and membership functions, and the shipped ones (one JSON file per
airframe, made by `ivfm identify --out`)."""
