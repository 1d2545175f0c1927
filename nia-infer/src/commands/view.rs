//! `nia-infer view --model M --subject S [--frame F] [--views 0,2,4] [--port P] [--host H]`:
//! the interactive viewer ([`crate::viewer`]) on a local HTTP server.

use std::sync::Arc;

use anyhow::Context;
use clap::Args;

use crate::session::{RenderSession, SessionArgs};
use crate::viewer::server::{serve, Viewer};
use crate::viewer::ViewerScene;

#[derive(Args, Debug)]
pub struct ViewArgs {
    #[command(flatten)]
    pub session: SessionArgs,
    /// The reference frame: its images are the sources for every pose.
    #[arg(long, default_value_t = 0)]
    pub frame: usize,
    /// Port (0: any free port; the URL says which).
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Address to listen on; the default serves this machine only.
    #[arg(long, default_value = "127.0.0.1")]
    pub host: String,
}

pub fn run(args: &ViewArgs) -> anyhow::Result<()> {
    let session = RenderSession::open(&args.session)?;
    session.opened.check_frame("--frame", args.frame)?;
    let scene = ViewerScene::new(session, args.frame)?;
    let encode = scene.encode_seconds;
    let address = format!("{}:{}", args.host, args.port);
    let server = tiny_http::Server::http(&address)
        .map_err(|e| anyhow::anyhow!("{e}"))
        .with_context(|| format!("listening on {address}"))?;
    let url = match server.server_addr().to_ip() {
        Some(a) => format!("http://{a}/"),
        None => format!("http://{address}/"),
    };
    // The URL is the first line on stdout (tests and scripts read it).
    println!("{url}");
    eprintln!("scene encoded in {encode:.2} s; serving until interrupted (Ctrl-C)");
    serve(Arc::new(server), Arc::new(Viewer::new(scene)));
    Ok(())
}
