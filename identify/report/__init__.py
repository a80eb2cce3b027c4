"""Reports of an identification: the terminal summary (``terminal``), the HTML report (``html``, ``figures``,
``headline``) and the HTML pages of ``identify compare`` (``compare_html``) and ``acquire verify`` (``verify_html``)."""
