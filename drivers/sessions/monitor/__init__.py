"""The monitor's model: what `foldcell monitor` shows, aggregated from samples and liveliness.

`model.MonitorModel` is pure (no Zenoh; fed raw samples and liveliness events); `live.MonitorSession`
connects it to a Wire; `render.render_text` draws a snapshot for the terminal.
"""
