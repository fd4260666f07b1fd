"""Running an ego-motion model on a sequence: the frames at the model's resolution (:mod:`~ocalib.inference.view`)
and the batched prediction loop (:mod:`~ocalib.inference.predict`)."""
