//! The files a finished still with a PNG output and render passes has
//! beside it (`NAME.albedo.png`, `NAME.normal.png`, `NAME.depth.exr`; see
//! `trevi_core::aov::aov_path`), and each frame of a PNG sequence beside
//! that frame (`shot_01.albedo.png`…), downloaded beside the output as the
//! coordinator wrote them (`DownloadAov`, with the frame for a sequence).
//! An EXR output holds its passes as layers: nothing more to download.

use anyhow::{bail, Context, Result};
use std::path::Path;
use trevi_core::{Aov, Aovs};
use trevi_proto::pb;

use super::connect::status_error;
use super::download::PartFile;
use super::Client;

impl Client {
    /// Downloads every pass file of finished still `s` (`frame` `None`), or
    /// of frame `frame` of sequence `s`, beside `out` (that image's path
    /// here); returns where they went.
    pub async fn download_aovs(
        &mut self,
        s: &pb::JobStatus,
        frame: Option<u32>,
        out: &Path,
    ) -> Result<Vec<std::path::PathBuf>> {
        let aovs = Aovs::parse(&s.aovs)
            .with_context(|| format!("job {}'s render passes \"{}\"", s.id, s.aovs))?;
        let mut written = Vec::new();
        for aov in aovs.iter() {
            let Some(path) = trevi_core::aov::aov_path(out, aov) else {
                continue;
            };
            self.download_aov(s.id, frame, aov, &path)
                .await
                .with_context(|| format!("the {} pass of job {}", aov.name(), s.id))?;
            written.push(path);
        }
        Ok(written)
    }

    /// Downloads pass `aov`'s file of job `id` (of its frame `frame`, for a
    /// sequence) to `path` (through a part file renamed into place when
    /// complete).
    async fn download_aov(
        &mut self,
        id: u64,
        frame: Option<u32>,
        aov: Aov,
        path: &Path,
    ) -> Result<u64> {
        use tokio::io::AsyncWriteExt;
        let mut stream = self
            .jobs
            .download_aov(pb::AovFileRequest {
                id,
                aov: aov.name().to_string(),
                frame,
            })
            .await
            .map_err(status_error)?
            .into_inner();
        let mut tmp = PartFile::new(path).await?;
        let mut file = tokio::fs::File::create(&tmp.path)
            .await
            .with_context(|| format!("cannot write {}", tmp.path.display()))?;
        let (mut size, mut got) = (None, 0u64);
        while let Some(c) = stream.message().await.map_err(status_error)? {
            size.get_or_insert(c.size);
            got += c.data.len() as u64;
            file.write_all(&c.data).await?;
        }
        file.sync_all().await?;
        drop(file);
        if size.unwrap_or(0) != got {
            bail!("the download stopped at {got} of {size:?} bytes");
        }
        tmp.persist(path).await?;
        Ok(got)
    }
}
