"""Per-frame stages, one plug-in each, in the order data flows through them."""
