"""The web page (static files: index.html, app.js, style.css, vendor/), served by limbstream.services.dashboard."""
