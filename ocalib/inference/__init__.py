"""Running an ego-motion model on a sequence: the batched prediction loop (:mod:`~ocalib.inference.predict`, on the
frames :mod:`~ocalib.data.model_view` prepares) and the export of a trained model (:mod:`~ocalib.inference.export`)."""
