"""What boresight writes for people and other tools: the report of the paper's claims
(:mod:`~boresight.outputs.report`), plots (:mod:`~boresight.outputs.plots`), h_n for SO's tools
(:mod:`~boresight.outputs.so`) and h_{n,m} in litebird_sim's layout
(:mod:`~boresight.outputs.litebird`)."""
