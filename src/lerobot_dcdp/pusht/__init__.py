"""PushT helpers: T-block geometry, a privileged scripted expert and the demonstration recorder."""
